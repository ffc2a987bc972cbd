//! An orbit camera: [`Camera`] circles a target point at a distance, with a right-handed,
//! y-up perspective projection in OpenGL clip space, and sets the three camera uniforms the
//! product shaders read.

use crate::program::Program;
use glam::camera::rh;
use glam::{Mat4, Vec2, Vec3};

/// The model matrix uniform (`mat4`).
pub const UNIFORM_MODEL: &str = "ndf_model";
/// The projection × view matrix uniform (`mat4`).
pub const UNIFORM_VIEW_PROJ: &str = "ndf_view_proj";
/// The world-space eye position uniform (`vec3`).
pub const UNIFORM_CAMERA_POS: &str = "ndf_camera_pos";

/// A camera orbiting `target`; angles in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// The point looked at and orbited.
    pub target: Vec3,
    /// Distance from the target to the eye.
    pub distance: f32,
    /// Rotation about +y: 0 puts the eye on the +z side of the target, π/2 on the +x side.
    pub yaw: f32,
    /// Elevation above the target's horizontal plane, within ±(π/2 − 0.001).
    pub pitch: f32,
    /// Vertical field of view.
    pub fov_y: f32,
    /// Width / height of the image.
    pub aspect: f32,
    /// Near clip distance.
    pub near: f32,
    /// Far clip distance.
    pub far: f32,
    /// Offset of the image in normalized device coordinates (one pixel is `2/width` by
    /// `2/height`): sub-pixel jitter for supersampling. Zero by default.
    pub jitter: Vec2,
}

impl Default for Camera {
    /// The origin seen from 3 units along +z, 45° field of view, square image, clip 0.05–100,
    /// no jitter.
    fn default() -> Self {
        Camera {
            target: Vec3::ZERO,
            distance: 3.0,
            yaw: 0.0,
            pitch: 0.0,
            fov_y: 45f32.to_radians(),
            aspect: 1.0,
            near: 0.05,
            far: 100.0,
            jitter: Vec2::ZERO,
        }
    }
}

impl Camera {
    /// Largest |pitch|, short of the poles where the up vector degenerates.
    const MAX_PITCH: f32 = std::f32::consts::FRAC_PI_2 - 0.001;

    /// The eye position in world space.
    pub fn eye(&self) -> Vec3 {
        let pitch = self.pitch.clamp(-Self::MAX_PITCH, Self::MAX_PITCH);
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        self.target + self.distance * Vec3::new(cp * sy, sp, cp * cy)
    }

    /// World → view (right-handed, looking down −z, +y up).
    pub fn view(&self) -> Mat4 {
        rh::view::look_at_mat4(self.eye(), self.target, Vec3::Y)
    }

    /// View → OpenGL clip space (depth −1..1), shifted by [`Camera::jitter`].
    pub fn projection(&self) -> Mat4 {
        let shift = Mat4::from_translation(self.jitter.extend(0.0));
        shift * rh::proj::opengl::perspective(self.fov_y, self.aspect, self.near, self.far)
    }

    /// `projection · view`.
    pub fn view_proj(&self) -> Mat4 {
        self.projection() * self.view()
    }

    /// Turns the orbit by `d_yaw` and `d_pitch` (pitch kept off the poles).
    pub fn orbit(&mut self, d_yaw: f32, d_pitch: f32) {
        self.yaw += d_yaw;
        self.pitch = (self.pitch + d_pitch).clamp(-Self::MAX_PITCH, Self::MAX_PITCH);
    }

    /// Multiplies the distance by `factor` (below 1 moves closer).
    pub fn zoom(&mut self, factor: f32) {
        self.distance *= factor;
    }

    /// Sets `ndf_model` = `model`, `ndf_view_proj` and `ndf_camera_pos` on `program`, skipping
    /// the ones it lacks.
    pub fn set_uniforms(&self, program: &Program, model: &Mat4) {
        program.set_mat4(UNIFORM_MODEL, model);
        program.set_mat4(UNIFORM_VIEW_PROJ, &self.view_proj());
        program.set_vec3(UNIFORM_CAMERA_POS, self.eye());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_camera_places_the_eye_and_centres_the_target() {
        let mut c = Camera::default();
        assert!((c.eye() - Vec3::new(0.0, 0.0, 3.0)).length() < 1e-6);
        c.orbit(std::f32::consts::FRAC_PI_2, 0.0);
        assert!((c.eye() - Vec3::new(3.0, 0.0, 0.0)).length() < 1e-5);
        c.orbit(0.0, 10.0);
        assert!(c.pitch < std::f32::consts::FRAC_PI_2 && c.eye().y > 2.99);
        c.target = Vec3::new(1.0, 2.0, 3.0);
        let clip = c.view_proj() * c.target.extend(1.0);
        assert!(clip.x.abs() < 1e-4 && clip.y.abs() < 1e-4 && clip.w > 0.0);
        // Jitter moves every point by the same offset in normalized device coordinates.
        c.jitter = Vec2::new(0.01, -0.02);
        let clip = c.view_proj() * c.target.extend(1.0);
        let ndc = clip.truncate().truncate() / clip.w;
        assert!((ndc - c.jitter).length() < 1e-5);
    }
}
