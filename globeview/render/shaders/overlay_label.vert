#version 330
// Labels: a screen-aligned quad of the label's atlas rect size (pixels), to the right of the
// object's ground point, at the point's depth (biased toward the eye like the placemarks).
#include "view.glsl"
#include "log_depth.glsl"
#include "relative_position.glsl"
#include "ellipsoid.glsl"

uniform vec2 u_viewport;
uniform float u_depth_bias;
uniform sampler2D u_rects;     // (labels x 1) RGBA32F: x0, y0, width, height in atlas pixels
uniform vec2 u_atlas_size;
uniform float u_offset_px;

in vec3 in_hi;
in vec3 in_lo;
in float in_scale;
in float in_heading;
in float in_label;

out vec2 v_tex;

void main() {
    vec3 rel = gv_rel_to_eye(in_hi, in_lo);  // anchor - eye, metres
    vec3 cam = u_rot * rel;
    vec4 c = u_proj * vec4(cam, 1.0);
    float w = max(-cam.z, 1e-6);
    vec4 r = texelFetch(u_rects, ivec2(int(in_label + 0.5), 0), 0);
    vec2 corner = vec2((gl_VertexID & 1) == 0 ? 0.0 : 1.0, gl_VertexID < 2 ? 0.0 : 1.0);
    // Snap the anchor to whole pixels so the bitmap font stays crisp.
    vec2 anchor = floor((c.xy / c.w * 0.5 + 0.5) * u_viewport) + vec2(u_offset_px, 0.0);
    vec2 px = anchor + corner * r.zw;
    gl_Position = vec4((px / u_viewport * 2.0 - 1.0) * c.w, 0.0, c.w);
    gl_Position.z = (gv_log_depth(w) - 2.0 * u_depth_bias) * c.w;
    v_tex = (r.xy + vec2(corner.x, 1.0 - corner.y) * r.zw) / u_atlas_size;
    // Labels have no depth test (they stand beside their point, over nearer terrain), so hide
    // those whose point is past the ellipsoid's horizon: its ground normal faces away.
    vec3 normal = gv_ellipsoid_up(in_hi);
    bool behind = dot(normal, -rel) < -1e-3 * length(rel);
    if (cam.z >= 0.0 || behind) gl_Position = GV_OFFSCREEN;
}
