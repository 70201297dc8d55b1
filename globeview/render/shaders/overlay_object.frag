#version 330
uniform vec3 u_light;   // ECEF unit vector toward the light
in vec3 v_nrm;
flat in vec4 v_color;   // the object's own colour
out vec4 f_color;
void main() {
    float d = max(dot(normalize(v_nrm), u_light), 0.0);
    f_color = vec4(v_color.rgb * (0.45 + 0.55 * d), v_color.a);
}
