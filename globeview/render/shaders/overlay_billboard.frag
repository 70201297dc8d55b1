#version 330
uniform vec4 u_color;
in vec2 v_corner;
out vec4 f_color;
void main() {
    float r = length(v_corner);
    if (r > 1.0) discard;
    f_color = r > 0.7 ? vec4(0.05, 0.05, 0.05, 1.0) : u_color;  // dark rim, filled disc
}
