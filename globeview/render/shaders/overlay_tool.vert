#version 330
// Tool overlays (overlay_tools.py): screen-space discs (markers) and screen-space-wide quads
// (polyline segments), one instance each. Markers and on-top segments are drawn with no depth
// test; depth-tested segments carry the logarithmic depth (log_depth.glsl; pulled toward the
// eye by u_depth_bias, as vector layers are) so the terrain in front of them hides them.
// Positions arrive relative to the eye (float64 on the CPU -> float32 here): no absolute ECEF
// coordinate ever reaches the GPU.

#include "view.glsl"
#include "log_depth.glsl"

uniform vec2 u_viewport;  // pixels
uniform float u_depth_bias;  // window-depth pull toward the eye (a fixed fraction of w)

in vec3 in_a;             // marker position / segment start, relative to the eye (m)
in vec3 in_b;             // segment end (markers: = in_a)
in vec4 in_color;
in float in_size;         // marker diameter / line width (px)
in float in_kind;         // 0 = marker, 1 = segment
in float in_depth;        // 1: depth-tested segment

out vec4 v_color;
out vec2 v_local;         // markers: -1..1 across the disc; segments: (0, -1..1 across)
flat out float v_kind;
flat out float v_size;

void main() {
    int id = gl_VertexID;                       // 4-vertex triangle strip
    vec2 corner = vec2((id == 1 || id == 3) ? 1.0 : -1.0, (id >= 2) ? 1.0 : -1.0);
    vec3 ca = u_rot * in_a;
    vec3 cb = u_rot * in_b;
    v_color = in_color;
    v_kind = in_kind;
    v_size = in_size;
    if (-ca.z <= 0.0 || -cb.z <= 0.0) {         // behind the eye: drop
        gl_Position = GV_OFFSCREEN;
        v_local = vec2(0.0);
        return;
    }
    vec4 pa = u_proj * vec4(ca, 1.0);
    vec4 pb = u_proj * vec4(cb, 1.0);
    vec2 sa = pa.xy / pa.w;                      // NDC
    vec2 sb = pb.xy / pb.w;
    vec2 to_ndc = 2.0 / u_viewport;
    vec2 ndc;
    float w_here = -ca.z;
    if (in_kind < 0.5) {
        // One extra pixel of margin for the anti-aliased rim.
        float r = 0.5 * in_size + 1.0;
        ndc = sa + corner * r * to_ndc;
        v_local = corner * (r / (0.5 * in_size));
    } else {
        vec2 d = (sb - sa) / to_ndc;             // pixels
        float len = length(d);
        vec2 dir = len > 1e-6 ? d / len : vec2(1.0, 0.0);
        vec2 nrm = vec2(-dir.y, dir.x);
        float half_w = 0.5 * in_size + 0.5;
        bool at_b = corner.y > 0.0;
        // Half a pixel along the segment closes the joints between segments.
        vec2 off = nrm * corner.x * half_w + dir * (at_b ? 0.5 : -0.5);
        ndc = (at_b ? sb : sa) + off * to_ndc;
        w_here = at_b ? -cb.z : -ca.z;
        v_local = vec2(0.0, corner.x * half_w / max(0.5 * in_size, 0.5));
    }
    // Logarithmic window depth, linear on screen between the endpoints: the CPU cuts
    // depth-tested segments short enough for that to follow them.
    float z = in_depth > 0.5 ? gv_log_depth(w_here) - 2.0 * u_depth_bias : 0.0;
    gl_Position = vec4(ndc, z, 1.0);
}
