#version 330
// Small boxes (overlay_points.py) as one point sprite each, ray-cast in the fragment shader
// (overlay_box_sprite.frag). On llvmpipe vertex work is single-threaded and every instance of
// an instanced draw pays a fixed cost (about 3 us, more than its 36 vertices), while fragments
// run on every core: one vertex per box moves the work to where it is cheap. The CPU sends
// here only boxes whose sprite stays under the point size limit and inside the viewport
// (points are clipped by their centre); the others are drawn as meshes (overlay_object.vert).
//
// The box is the unit box (x, y in -0.5..0.5, z 0..1) of overlay_object.vert, placed by its
// ground point (hi/lo ECEF pair, relative to the eye) and its three axes in ECEF metres (east,
// north turned by the heading, up; each as long as the box), which the CPU computes once when
// the box is paged in.
#include "view.glsl"
#include "relative_position.glsl"

uniform mat3 u_ndc_to_ecef; // NDC (x, y, 1) -> ECEF direction of that pixel's ray, at view depth 1
uniform vec3 u_light;       // ECEF unit vector toward the light
uniform float u_px_m;       // metres per pixel at unit view distance

in vec3 in_hi;
in vec3 in_lo;
in vec3 in_ax;
in vec3 in_ay;
in vec3 in_az;
in vec4 in_color;           // RGBA 0..1, one per box

// The pixel's ray in box units is v_ray * (ndc.x, ndc.y, 1), its parameter t the view depth
// (m); v_origin is the eye and v_light the light direction in box axes.
flat out mat3 v_ray;
flat out vec3 v_origin;
flat out vec3 v_light;
flat out vec4 v_color;

void main() {
    vec3 base = gv_rel_to_eye(in_hi, in_lo);
    float s2 = dot(in_az, in_az);                     // the box's size squared (m^2)
    mat3 to_box = transpose(mat3(in_ax, in_ay, in_az)) / s2;  // ECEF metres -> box units
    v_origin = -(to_box * base);
    v_ray = to_box * u_ndc_to_ecef;
    v_light = normalize(transpose(mat3(in_ax, in_ay, in_az)) * u_light);
    v_color = in_color;
    vec3 cam = u_rot * (base + 0.5 * in_az);
    gl_Position = u_proj * vec4(cam, 1.0);
    float w = max(-cam.z, 1e-6);
    // Half the screen extent (px) of the bounding sphere (radius sqrt(3)/2 size) around its
    // centre's image: r d / (w^2 px_m) for a sphere at distance d and view depth w, to first
    // order in r / d (under 0.1 for a sprite: the 2 % and a quarter pixel cover the rest).
    // The CPU's test (overlay_points.sprite_classes) uses a larger bound.
    float half_px = 0.8660254 * sqrt(s2) * length(cam) / (w * w * u_px_m);
    gl_PointSize = 2.04 * half_px + 0.5;
    gl_Position.z = 0.0;   // the fragment shader writes the hit's depth
    if (cam.z >= 0.0) gl_Position = GV_OFFSCREEN;
}
