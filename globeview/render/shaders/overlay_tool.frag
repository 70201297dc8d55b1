#version 330
// Markers: a filled disc with a dark rim (visible on any terrain colour); segments: solid,
// anti-aliased across their width.

in vec4 v_color;
in vec2 v_local;
flat in float v_kind;
flat in float v_size;
out vec4 f_color;

void main() {
    float px = 0.5 * v_size;                     // pixels per unit of v_local
    if (v_kind < 0.5) {
        float r = length(v_local) * px;          // distance from the centre, pixels
        float cover = clamp(px + 0.5 - r, 0.0, 1.0);
        if (cover <= 0.0) discard;
        float rim = smoothstep(px - 2.5, px - 1.5, r);
        vec3 c = mix(v_color.rgb, vec3(0.05), rim);
        f_color = vec4(c, v_color.a * cover);
    } else {
        float d = abs(v_local.y) * max(px, 0.5);
        float cover = clamp(max(px, 0.5) + 0.5 - d, 0.0, 1.0);
        if (cover <= 0.0) discard;
        f_color = vec4(v_color.rgb, v_color.a * cover);
    }
}
