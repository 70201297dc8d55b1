#version 330
uniform sampler2D u_atlas;
uniform vec4 u_color;
in vec2 v_tex;
out vec4 f_color;
void main() {
    float a = texture(u_atlas, v_tex).r;
    if (a < 0.05) discard;
    f_color = vec4(u_color.rgb, u_color.a * a);
}
