#version 330
// Shading: hypsometric colour ramp with a separate bathymetry ramp, directional light or a
// hillshade, fog toward the horizon, and an optional wireframe overlay.
//
// Depth is logarithmic, computed in the vertex shader (log_depth.glsl says why).
#include "ellipsoid.glsl"

uniform sampler2DArray u_heights;
uniform sampler2DArray u_normals;
uniform sampler2D u_ramp;        // colour by height: u in [0, 1] over [u_ramp_lo, u_ramp_hi]
uniform float u_ramp_lo;
uniform float u_ramp_hi;
uniform float u_exag;
uniform vec3 u_light;            // ECEF unit vector toward the light
uniform bool u_hillshade;        // light from the north-west, 45 degrees up, in each local frame
uniform float u_fog_start;       // metres
uniform float u_fog_end;         // metres
uniform vec3 u_fog_color;
uniform int u_mode;              // 0 = shaded, 1 = wireframe overlay
uniform vec3 u_wire_color;
// overlays: imagery drape (overlay_imagery.py): premultiplied RGBA per tile, one-texel border.
uniform sampler2DArray u_imagery;
uniform float u_imagery_on;       // 0 or 1
uniform float u_imagery_opacity;  // 0..1
uniform float u_imagery_size;     // texels per tile side, border included
uniform float u_tile_nodes;       // nodes per terrain tile side

in vec2 v_uv;
flat in float v_layer;
in vec3 v_up;
in vec3 v_rel;
in float v_shade;

out vec4 f_color;

void main() {
    if (u_mode == 1) {
        f_color = vec4(u_wire_color, 1.0);
        return;
    }
    float h = texture(u_heights, vec3(v_uv, v_layer)).r;
    vec3 n = normalize(texture(u_normals, vec3(v_uv, v_layer)).xyz * 2.0 - 1.0);
    vec3 up = normalize(v_up);
    // Exaggeration scales slopes: tilt the stored (true-relief) normal accordingly.
    float nu = dot(n, up);
    n = normalize(u_exag * (n - nu * up) + nu * up);

    vec3 albedo = texture(u_ramp, vec2(clamp((h - u_ramp_lo) / (u_ramp_hi - u_ramp_lo), 0.0, 1.0), 0.5)).rgb;
#ifdef GV_IMAGERY
    if (u_imagery_on > 0.5) {  // overlays: node uv -> tile fraction -> interior texels
        vec2 t = (v_uv * u_tile_nodes - 0.5) / (u_tile_nodes - 1.0);
        vec2 iuv = (1.0 + t * (u_imagery_size - 2.0)) / u_imagery_size;
        vec4 img = texture(u_imagery, vec3(iuv, v_layer)) * u_imagery_opacity;
        albedo = albedo * (1.0 - img.a) + img.rgb;
    }
#endif

    vec3 light = u_light;
#ifdef GV_HILLSHADE
    if (u_hillshade) {
        vec3 east, north;
        gv_east_north(up, east, north);
        light = normalize(0.5 * (-east + north) + 0.7071 * up);
    }
#endif
    float diffuse = max(dot(n, light), 0.0);
    vec3 color = albedo * (0.35 + 0.75 * diffuse);

    // Interpolating 1.0 across a triangle can give 0.99999994: snap it back to exactly 1 so
    // a hook that shades nothing changes no pixel.
    color *= min(v_shade + 1e-3, 1.0);
#ifdef GV_FOG
    float fog = smoothstep(u_fog_start, u_fog_end, length(v_rel));
    color = mix(color, u_fog_color, fog * 0.6);
#endif
    f_color = vec4(color, 1.0);
}
