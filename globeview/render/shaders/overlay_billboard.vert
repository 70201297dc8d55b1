#version 330
// Placemarks (overlay_points.py): one camera-facing square of in_scale pixels per instance,
// at the object's ground point (hi/lo ECEF pairs relative to the eye's), its depth pulled a
// little toward the eye so it is not buried by the surface it stands on.
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

out vec2 v_corner;
flat out vec4 v_color;

void main() {
    vec3 cam = u_rot * gv_rel_to_eye(in_hi, in_lo);
    vec4 c = u_proj * vec4(cam, 1.0);
    float w = max(-cam.z, 1e-6);
    vec2 corner = vec2((gl_VertexID & 1) == 0 ? -1.0 : 1.0, gl_VertexID < 2 ? -1.0 : 1.0);
    v_corner = corner;
    v_color = in_color;
    // The point is the bottom-centre tip of the marker.
    vec2 off = (corner + vec2(0.0, 1.0)) * 0.5 * in_scale * 2.0 / u_viewport;
    gl_Position = vec4(c.xy + off * c.w, 0.0, c.w);
    gl_Position.z = (gv_log_depth(w) - 2.0 * u_depth_bias) * c.w;
    if (cam.z >= 0.0) gl_Position = GV_OFFSCREEN;
}
