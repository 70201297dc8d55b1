#version 330
// Ray-cast box sprite (overlay_box_sprite.vert): the pixel's ray through the unit box
// (slab test in the box frame), shaded and depth-tested like the mesh (overlay_object.*):
// the entry face's normal lit by the light, the log depth of the hit written per fragment.
#include "log_depth.glsl"

uniform vec2 u_viewport;   // pixels

flat in mat3 v_ray;
flat in vec3 v_origin;
flat in vec3 v_light;
flat in vec4 v_color;      // the box's own colour
out vec4 f_color;

void main() {
    vec3 dl = v_ray * vec3(gl_FragCoord.xy / u_viewport * 2.0 - 1.0, 1.0);
    // Keep every component away from 0 (a ray parallel to a face) so the slabs stay finite.
    dl = mix(dl, vec3(1e-12), lessThan(abs(dl), vec3(1e-12)));
    vec3 inv = 1.0 / dl;
    vec3 t1 = (vec3(-0.5, -0.5, 0.0) - v_origin) * inv;
    vec3 t2 = (vec3(0.5, 0.5, 1.0) - v_origin) * inv;
    vec3 tn = min(t1, t2);
    vec3 tf = max(t1, t2);
    float t0 = max(max(tn.x, tn.y), tn.z);
    float t3 = min(min(tf.x, tf.y), tf.z);
    if (t3 < t0 || t0 <= 0.0) discard;
    // The entry face (the slab whose near plane the ray meets last); its outward normal in
    // box axes, lit as overlay_object.frag lights the mesh's face normal.
    vec3 n = t0 == tn.x ? vec3(-sign(dl.x), 0.0, 0.0)
           : (t0 == tn.y ? vec3(0.0, -sign(dl.y), 0.0) : vec3(0.0, 0.0, -sign(dl.z)));
    float lit = max(dot(n, v_light), 0.0);
    f_color = vec4(v_color.rgb * (0.45 + 0.55 * lit), v_color.a);
    gl_FragDepth = log2(1.0 + t0) * u_log_far;   // window depth of the hit (view depth t0)
}
