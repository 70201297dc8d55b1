#version 330
uniform vec4 u_color;
uniform vec3 u_light;   // ECEF unit vector toward the light
in vec3 v_nrm;
out vec4 f_color;
void main() {
    float d = max(dot(normalize(v_nrm), u_light), 0.0);
    f_color = vec4(u_color.rgb * (0.45 + 0.55 * d), u_color.a);
}
