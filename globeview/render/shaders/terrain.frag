#version 330
// Shading: the node colours baked from the hypsometric ramp (colour_ramp.albedo_texels: land
// and bathymetry ramps), directional light or a hillshade, fog toward the horizon; or, with
// GV_WIREFRAME, the wireframe overlay's one colour (its own program variant).
//
// Depth is logarithmic, computed in the vertex shader (log_depth.glsl says why).
//
// Cost (issue #17; benchmarks/bench_fragment.py): on llvmpipe every fragment runs on the
// CPU, so this shader does two RGBA8 fetches (albedo, normal) and a few multiply-adds. What
// could be was moved out: the ramp lookup is baked per tile at upload (it replaced a float32
// height fetch and a dependent ramp fetch); fog and the hillshade light are computed per
// vertex and interpolated (both vary smoothly across a triangle); the exaggeration tilt
// (GV_TILT) and the displacement hook's shade factor (GV_SHADE) are compiled in only when
// the exaggeration is not 1 or a hook is installed, and the wireframe pass is a variant of
// its own (a uniform branch costs both sides on llvmpipe). The same defines go to
// terrain.vert.

uniform sampler2DArray u_albedo;   // RGBA8: ramp colour of each node; alpha: its coast blend t
uniform sampler2DArray u_normals;  // RGBA8: unit ECEF normal * 0.5 + 0.5 of each node; alpha:
                                   // its height over the tile's coast scale, * 0.5 + 0.5
// Coasts (colour_ramp.COAST_MIN_M says how): the ramp's colour step from water to land.
uniform vec3 u_coast_jump;
uniform float u_exag;
uniform vec3 u_light;            // ECEF unit vector toward the light
uniform vec3 u_wire_color;       // GV_WIREFRAME
uniform vec3 u_fog_color;
// overlays: imagery drape (overlay_imagery.py): premultiplied RGBA per tile, one-texel border.
uniform sampler2DArray u_imagery;
uniform float u_imagery_on;       // 0 or 1
uniform float u_imagery_opacity;  // 0..1
uniform float u_imagery_size;     // texels per tile side, border included
uniform float u_tile_nodes;       // nodes per terrain tile side

in vec2 v_uv;
flat in float v_layer;
flat in vec3 v_coast;            // (x, y): the coast blend (unclamped) at the normal's alpha
                                 // a is a * x + y; z: how far at.a may move it (terrain.vert)
#ifdef GV_TILT
in vec3 v_up;                    // unit ellipsoid normal at the vertices (interpolated)
#endif
#ifdef GV_HILLSHADE
in vec3 v_hill_light;            // the local north-west light (ECEF), per vertex
#endif
#ifdef GV_SHADE
in float v_shade;                // the displacement hook's shade factor (1 = unshaded)
#endif
#ifdef GV_FOG
in float v_fog;                  // fog amount, 0..0.6
#endif

out vec4 f_color;

void main() {
#ifdef GV_WIREFRAME
    f_color = vec4(u_wire_color, 1.0);
#else
    vec4 at = texture(u_albedo, vec3(v_uv, v_layer));
    vec4 nt = texture(u_normals, vec3(v_uv, v_layer));
    vec3 n = nt.xyz * 2.0 - 1.0;
    // Sharp coasts: the baked colours blend water into land across a whole texel; replace
    // that blend (the node weights, interpolated: at.a) by the one at the interpolated
    // height, as the per-pixel ramp drew it. Zero where a cell has no coast.
    // Two estimates of the blend before its clamp: from the normal's alpha, the height over
    // the tile's scale (the coast where the interpolated height crosses 0 m, but in whole
    // 8-bit codes: llvmpipe filters RGBA8 to codes, s / 127.5 m); and at.a, the node weights
    // interpolated (exact where the cell's nodes all lie in the ~20 m band, wrong where one
    // is beyond it). The second may move the first by a fraction of a code (v_coast.z).
    float u = nt.a * v_coast.x + v_coast.y;
    u += clamp(at.a - u, -v_coast.z, v_coast.z);
    float t = clamp(u, 0.0, 1.0);
    vec3 albedo = at.rgb + u_coast_jump * (t - at.a);
#ifdef GV_IMAGERY
    if (u_imagery_on > 0.5) {  // overlays: node uv -> tile fraction -> interior texels
        vec2 t = (v_uv * u_tile_nodes - 0.5) / (u_tile_nodes - 1.0);
        vec2 iuv = (1.0 + t * (u_imagery_size - 2.0)) / u_imagery_size;
        vec4 img = texture(u_imagery, vec3(iuv, v_layer)) * u_imagery_opacity;
        albedo = albedo * (1.0 - img.a) + img.rgb;
    }
#endif

#ifdef GV_HILLSHADE
    vec3 light = normalize(v_hill_light);  // interpolated: a little short mid-triangle
#else
    vec3 light = u_light;
#endif
    float nn = dot(n, n);
#ifdef GV_TILT
    // Exaggeration scales slopes: the lit normal is normalize(e (n - nu up) + nu up), with
    // nu = n.up and e = u_exag. Its dot with the light is e n.l + (1 - e) nu up.l, and its
    // squared length e^2 (n.n - nu^2) + nu^2 (the two parts are orthogonal): the diffuse
    // term without building the tilted vector. At e = 1 it is n.l / |n| (below).
    vec3 up = v_up;
    float nu = dot(n, up);
    float lit = u_exag * dot(n, light) + (1.0 - u_exag) * nu * dot(up, light);
    nn = u_exag * u_exag * (nn - nu * nu) + nu * nu;
#else
    float lit = dot(n, light);
#endif
    // The stored normal is 8-bit (|n| within 1 % of 1): normalised, as the tilted one.
    float diffuse = max(lit, 0.0) * inversesqrt(max(nn, 1e-12));
    vec3 color = albedo * (0.35 + 0.75 * diffuse);

#ifdef GV_SHADE
    // Interpolating 1.0 across a triangle can give 0.99999994: snap it back to exactly 1 so
    // a hook that shades nothing changes no pixel.
    color *= min(v_shade + 1e-3, 1.0);
#endif
#ifdef GV_FOG
    color = mix(color, u_fog_color, v_fog);
#endif
    f_color = vec4(color, 1.0);
#endif
}
