#version 330
// Terrain tiles, relative-to-centre (relative_position.glsl): positions arrive relative to the
// tile centre (float32, small), and the tile centre relative to the eye is computed per draw
// in float64 on the CPU.
//
// Besides the position, this shader computes per vertex what varies smoothly enough to be
// interpolated rather than evaluated per fragment (terrain.frag says why): the fog amount
// (GV_FOG) and the local north-west light (GV_HILLSHADE). It gets the fragment shader's
// feature defines, so it writes only the outputs that variant reads.
#include "view.glsl"
#include "log_depth.glsl"
#include "relative_position.glsl"
#include "ellipsoid.glsl"

uniform float u_exag;        // vertical exaggeration (live)
uniform float u_depth_bias;  // pulls the wireframe overlay in front of the surface
uniform float u_fog_start;   // metres from the eye where fog begins
uniform float u_fog_end;     // metres from the eye where it is full (60 %)
uniform vec2 u_edge_push;    // x: metres per metre from the eye that stitched tile edges move
                             // outward (a fraction of a pixel); y: 1 / nodes per tile side

in vec3 in_pos;              // ellipsoid point (h = 0) relative to the tile centre, metres
in float in_h;               // height above the ellipsoid, metres
in vec2 in_uv;               // texel centre of this node in the tile's textures
in vec3 in_center_rel;       // per draw: tile centre - eye, metres
in vec3 in_center;           // per draw: tile centre, ECEF metres (for directions only)
in float in_layer;           // per draw: slot of the tile in the texture arrays
in float in_coast_scale;     // per draw: the tile's coast scale s, metres (colour_ramp.py)
in float in_edge_push;       // per draw: the edges stitched without skirts, 1 north + 2 south
                             // + 4 west + 8 east (gv_edge_push)
uniform vec2 u_coast_t;      // the coast blend t = clamp(h * x + y, 0, 1) at height h (m)
// How far (in 8-bit codes of the coast texel) terrain.frag lets the interpolated node blend
// move the blend from the coast texel: a quarter code (colour_ramp.COAST_MIN_M says why).
#define COAST_REFINE_CODES 0.25

out vec2 v_uv;
flat out float v_layer;
flat out vec3 v_coast;       // the coast blend from the textures' alphas (terrain.frag)
#ifdef GV_TILT
out vec3 v_up;
#endif
#ifdef GV_HILLSHADE
out vec3 v_hill_light;       // light from the north-west, 45 degrees up, in the local frame
#endif
#ifdef GV_SHADE
out float v_shade;           // shading factor a displacement hook may set (e.g. the collapse)
#endif
#ifdef GV_FOG
out float v_fog;             // fog amount (0..0.6) at this vertex
#endif

#define GV_HAS_SHADE 1
float gv_shade = 1.0;
// The identity, or the active tool's displacement_glsl() text in its place.
#include "displace.glsl"

// The outward offset of a tile's nodes on its stitched edges (in_edge_push), so that the
// tile overlaps its neighbour there by a fraction of a pixel. Two tiles draw a shared edge
// from their own float32 vertices, relative to their own centres, which round apart by
// ~1e-4 px: without skirts (an edge stitched to a same-level neighbour, lod/stitching.py)
// that left a background pixel along some edge about once a frame. Nodes on a skirted edge
// (a corner of a stitched one) stay put, as does every node of a tile with no stitched edge
// (the other providers'), and a pole (one point).
vec3 gv_edge_push(vec3 rel, vec3 up) {
    vec4 on = mod(floor(vec4(in_edge_push) / vec4(1.0, 2.0, 4.0, 8.0)), 2.0);  // N S W E
    vec2 last = step(1.0 - u_edge_push.y, in_uv);  // the east column, the south row
    vec2 first = step(in_uv, vec2(u_edge_push.y));  // the west column, the north row
    float skirted = dot(last, 1.0 - on.wy) + dot(first, 1.0 - on.zx);
    vec2 side = (last * on.wy - first * on.zx) * (1.0 - step(0.5, skirted));
    vec3 east, north;
    gv_east_north(up, east, north);
    float off_pole = step(1e-4, length(up.xy));
    vec3 dir = side.x * east - side.y * north;  // rows run north to south
    return dir * (u_edge_push.x * length(rel) * off_pole);
}

void main() {
    vec3 up = gv_ellipsoid_up(in_center + in_pos);
    vec3 rel = gv_rel_to_centre(in_center_rel, in_pos) + up * (in_h * u_exag);
    rel += gv_edge_push(rel, up);
    rel = gv_displace(rel, up, in_h * u_exag, in_center_rel);
    vec3 cam = u_rot * rel;
    gl_Position = u_proj * vec4(cam, 1.0);
    float w = max(-cam.z, 1e-6);
    gl_Position.z = (gv_log_depth(w) - u_depth_bias) * gl_Position.w;
    v_uv = in_uv;
    v_layer = in_layer;
    // The normal's alpha a is the height over the tile's scale s: h = (2 a - 1) s, so
    // h * x + y = a * 2ks + (y - ks) with k = u_coast_t.x; one 8-bit code of a is ks / 127.5.
    float k = in_coast_scale * u_coast_t.x;
    v_coast = vec3(2.0 * k, u_coast_t.y - k, COAST_REFINE_CODES * k / 127.5);
#ifdef GV_TILT
    v_up = up;
#endif
#ifdef GV_HILLSHADE
    vec3 east, north;
    gv_east_north(up, east, north);
    v_hill_light = normalize(0.5 * (-east + north) + 0.7071 * up);
#endif
#ifdef GV_SHADE
    v_shade = gv_shade;
#endif
#ifdef GV_FOG
    v_fog = 0.6 * smoothstep(u_fog_start, u_fog_end, length(rel));
#endif
}
