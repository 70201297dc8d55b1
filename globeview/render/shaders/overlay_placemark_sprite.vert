#version 330
// Placemarks (overlay_points.py) as one point sprite each: the square of overlay_billboard.vert
// (in_scale pixels, its bottom-centre at the object's ground point, depth pulled toward the
// eye) drawn as a point of that size centred half a square above the point. One vertex per
// placemark instead of an instance of four (llvmpipe pays about 2 us per instance); the CPU
// sends here only placemarks whose square lies inside the viewport (GL clips a point by its
// centre), the others go the billboard way.
#include "view.glsl"
#include "log_depth.glsl"
#include "relative_position.glsl"

uniform vec2 u_viewport;
uniform float u_depth_bias;

in vec3 in_hi;
in vec3 in_lo;
in float in_scale;      // pixels
in float in_heading;
in float in_label;
in vec4 in_color;       // RGBA 0..1, one per placemark

flat out vec4 v_color;

void main() {
    v_color = in_color;
    vec3 cam = u_rot * gv_rel_to_eye(in_hi, in_lo);
    vec4 c = u_proj * vec4(cam, 1.0);
    float w = max(-cam.z, 1e-6);
    gl_Position = vec4(c.xy + vec2(0.0, in_scale / u_viewport.y) * c.w, 0.0, c.w);
    gl_Position.z = (gv_log_depth(w) - 2.0 * u_depth_bias) * c.w;
    gl_PointSize = in_scale;
    if (cam.z >= 0.0) gl_Position = GV_OFFSCREEN;
}
