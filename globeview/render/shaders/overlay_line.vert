#version 330
// Draped polylines (overlay_vectors.py): one instance per segment, a 4-vertex strip widened
// to u_width pixels in screen space. Endpoints arrive as float32 hi/lo pairs of absolute ECEF
// metres; subtracting the eye's hi/lo pair keeps millimetres (relative_position.glsl).
#include "view.glsl"
#include "log_depth.glsl"
#include "relative_position.glsl"

uniform vec2 u_viewport;     // pixels
uniform float u_depth_bias;  // window-depth pull toward the eye (a fixed fraction of w)
uniform float u_width;       // pixels

in vec3 in_a_hi;
in vec3 in_a_lo;
in vec3 in_b_hi;
in vec3 in_b_lo;
in float in_along_a;         // metres along the polyline
in float in_along_b;
in float in_sag;             // metres the drawn terrain rises above this segment's chord

out float v_along;

vec4 clip_of(vec3 hi, vec3 lo, out float w) {
    vec3 rel = gv_rel_to_eye(hi, lo);
    vec3 cam = u_rot * rel;
    w = -cam.z;
    return u_proj * vec4(cam, 1.0);
}

void main() {
    float wa, wb;
    vec4 ca = clip_of(in_a_hi, in_a_lo, wa);
    vec4 cb = clip_of(in_b_hi, in_b_lo, wb);
    int id = gl_VertexID;
    bool at_b = (id >= 2);
    if (wa <= 0.0 || wb <= 0.0) {          // behind the eye: drop the segment
        gl_Position = GV_OFFSCREEN;
        v_along = 0.0;
        return;
    }
    vec2 sa = ca.xy / ca.w * u_viewport;
    vec2 sb = cb.xy / cb.w * u_viewport;
    vec2 d = sb - sa;
    float len = length(d);
    vec2 dir = len > 1e-6 ? d / len : vec2(1.0, 0.0);
    vec2 nrm = vec2(-dir.y, dir.x);
    float side = (id == 0 || id == 2) ? -1.0 : 1.0;
    vec4 c = at_b ? cb : ca;
    float w = at_b ? wb : wa;
    // Half a width each side, plus half a pixel along the segment to close joints.
    vec2 off = (nrm * side * 0.5 * u_width + dir * (at_b ? 0.5 : -0.5)) * 2.0 / u_viewport;
    gl_Position = vec4(c.xy + off * c.w, 0.0, c.w);
    // The chord between two draped vertices passes under a ridge between them: pull its depth
    // toward the eye by the terrain's rise over the chord (in_sag), divided by the cosine of
    // the incidence (the ray meets the hump that far before the chord), capped at 4 x and at
    // half the view depth, so terrain farther in front (a mountain) still hides the line.
    vec3 up = normalize(in_a_hi);
    float cos_i = abs(dot(up, normalize(gv_rel_to_eye(in_a_hi, in_a_lo))));
    float pull = min(in_sag / max(cos_i, 0.25), 0.5 * w);
    gl_Position.z = (gv_log_depth(w - pull) - 2.0 * u_depth_bias) * c.w;
    v_along = at_b ? in_along_b : in_along_a;
}
