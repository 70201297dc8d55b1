#version 330
// 3-D point objects (boxes, cones): a unit mesh (x east, y north, z up; base at z = 0) scaled
// by in_scale metres, turned by in_heading (radians clockwise from north) in the local
// east-north-up frame of its ground point, placed relative to the eye (hi/lo pairs).
#include "view.glsl"
#include "log_depth.glsl"
#include "relative_position.glsl"
#include "ellipsoid.glsl"

in vec3 in_vpos;
in vec3 in_vnrm;
in vec3 in_hi;
in vec3 in_lo;
in float in_scale;
in float in_heading;
in float in_label;
in vec4 in_color;       // RGBA 0..1, one per object

out vec3 v_nrm;
flat out vec4 v_color;

void main() {
    vec3 up = gv_ellipsoid_up(in_hi);
    vec3 east, north;
    gv_east_north(up, east, north);
    float ch = cos(in_heading), sh = sin(in_heading);
    // Heading clockwise from north: local x (east) turns toward south.
    vec3 ex = ch * east - sh * north;
    vec3 ny = sh * east + ch * north;
    mat3 frame = mat3(ex, ny, up);
    vec3 rel = gv_rel_to_eye(in_hi, in_lo) + frame * (in_vpos * in_scale);
    vec3 cam = u_rot * rel;
    gl_Position = u_proj * vec4(cam, 1.0);
    float w = max(-cam.z, 1e-6);
    gl_Position.z = gv_log_depth(w) * gl_Position.w;
    v_nrm = frame * in_vnrm;
    v_color = in_color;
}
