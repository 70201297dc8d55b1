#version 330
// The placemark disc of overlay_billboard.frag on a point sprite: gl_PointCoord (origin at
// the top left) gives the corner coordinate the billboard's quad interpolates.
flat in vec4 v_color;   // the placemark's own colour
out vec4 f_color;
void main() {
    vec2 corner = vec2(gl_PointCoord.x * 2.0 - 1.0, 1.0 - gl_PointCoord.y * 2.0);
    float r = length(corner);
    if (r > 1.0) discard;
    f_color = r > 0.7 ? vec4(0.05, 0.05, 0.05, 1.0) : v_color;  // dark rim, filled disc
}
