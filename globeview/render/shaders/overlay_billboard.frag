#version 330
in vec2 v_corner;
flat in vec4 v_color;   // the placemark's own colour
out vec4 f_color;
void main() {
    float r = length(v_corner);
    if (r > 1.0) discard;
    f_color = r > 0.7 ? vec4(0.05, 0.05, 0.05, 1.0) : v_color;  // dark rim, filled disc
}
