//! The render checks of `common` through the EGL device route (libEGL, Mesa llvmpipe).

mod common;

use ndfmap_gl::Route;

common::route_tests!(Route::Egl);
