#version 330
// 3-D point objects (boxes, cones): a unit mesh (x east, y north, z up; base at z = 0) scaled
// by in_scale metres, turned by in_heading (radians clockwise from north) in the local
// east-north-up frame of its ground point, placed relative to the eye (hi/lo pairs).
uniform mat3 u_rot;
uniform mat4 u_proj;
uniform vec3 u_eye_hi;
uniform vec3 u_eye_lo;
uniform vec3 u_inv_axes2;
uniform float u_log_far;

in vec3 in_vpos;
in vec3 in_vnrm;
in vec3 in_hi;
in vec3 in_lo;
in float in_scale;
in float in_heading;
in float in_label;

out vec3 v_nrm;

void main() {
    vec3 up = normalize(in_hi * u_inv_axes2);
    vec3 east = normalize(cross(vec3(0.0, 0.0, 1.0), up) + vec3(1e-9, 0.0, 0.0));
    vec3 north = cross(up, east);
    float ch = cos(in_heading), sh = sin(in_heading);
    // Heading clockwise from north: local x (east) turns toward south.
    vec3 ex = ch * east - sh * north;
    vec3 ny = sh * east + ch * north;
    mat3 frame = mat3(ex, ny, up);
    vec3 rel = (in_hi - u_eye_hi) + (in_lo - u_eye_lo) + frame * (in_vpos * in_scale);
    vec3 cam = u_rot * rel;
    gl_Position = u_proj * vec4(cam, 1.0);
    float w = max(-cam.z, 1e-6);
    gl_Position.z = (2.0 * log2(1.0 + w) * u_log_far - 1.0) * gl_Position.w;
    v_nrm = frame * in_vnrm;
}
