#version 330
// Tool marker labels: the glyph coverage in the label's colour over a one-pixel dark shadow
// (down-right), so the text reads on bright and dark terrain alike.
uniform sampler2D u_atlas;
uniform vec2 u_atlas_size;
in vec2 v_tex;
in vec4 v_color;
out vec4 f_color;

void main() {
    float a = texture(u_atlas, v_tex).r;
    float s = texture(u_atlas, v_tex + vec2(-1.0, -1.0) / u_atlas_size).r;
    float cover = max(a, s);
    if (cover < 0.05) discard;
    f_color = vec4(mix(vec3(0.0), v_color.rgb, a), v_color.a * cover);
}
