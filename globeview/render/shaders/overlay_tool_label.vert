#version 330
// Tool marker labels (overlay_tools.py): a screen-aligned quad of the label's atlas rect
// (pixels) to the right of the marker, snapped to whole pixels so the bitmap font stays crisp.
// Anchors arrive relative to the eye (float64 on the CPU -> float32 here). Drawn on top, like
// the markers; the CPU has dropped those beyond the horizon.
#include "view.glsl"

uniform vec2 u_viewport;  // pixels
uniform vec2 u_atlas_size;

in vec3 in_rel;           // the marker, relative to the eye (m)
in vec4 in_rect;          // x0, y0, width, height in atlas pixels (row 0 at the top)
in vec4 in_color;
in float in_offset;       // pixels from the marker's centre to the label's left edge

out vec2 v_tex;
out vec4 v_color;

void main() {
    vec3 cam = u_rot * in_rel;
    v_color = in_color;
    vec2 corner = vec2((gl_VertexID & 1) == 0 ? 0.0 : 1.0, gl_VertexID < 2 ? 0.0 : 1.0);
    v_tex = (in_rect.xy + vec2(corner.x, 1.0 - corner.y) * in_rect.zw) / u_atlas_size;
    if (-cam.z <= 0.0) {       // behind the eye
        gl_Position = GV_OFFSCREEN;
        return;
    }
    vec4 c = u_proj * vec4(cam, 1.0);
    // Vertically centred on the marker; y grows upward in NDC, the atlas rows downward.
    vec2 anchor = floor((c.xy / c.w * 0.5 + 0.5) * u_viewport)
        + vec2(in_offset, -floor(0.5 * in_rect.w));
    vec2 px = anchor + corner * in_rect.zw;
    gl_Position = vec4(px / u_viewport * 2.0 - 1.0, 0.0, 1.0);
}
