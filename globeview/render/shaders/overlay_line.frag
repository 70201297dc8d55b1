#version 330
uniform vec4 u_color;
uniform float u_dash;   // dash length in pixels (0 = solid)
uniform float u_px_m;   // metres per pixel at unit distance

in float v_along;
out vec4 f_color;

void main() {
    if (u_dash > 0.0) {
        // gl_FragCoord.w = 1 / w: metres along the line -> pixels at this depth.
        float px = v_along * gl_FragCoord.w / u_px_m;
        if (mod(px, 2.0 * u_dash) > u_dash) discard;
    }
    f_color = u_color;
}
