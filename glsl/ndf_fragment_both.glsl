#ifdef NDF_LIGHT_BOTH
// Set by the entry point: the view (tangent frame), the point light's scale (colour x falloff)
// and the environment's (its radiance scale).
vec3 ndf_view = vec3(0.0, 0.0, 1.0);
vec3 ndf_point_scale = vec3(1.0);
vec3 ndf_env_scale = vec3(1.0);
#endif
