#version 330
// Terrain tiles, relative-to-centre: positions arrive relative to the tile centre (float32,
// small), and the tile centre relative to the eye is computed per draw in float64 on the CPU.
// The camera sits at the origin of the space this shader works in, so no large ECEF value is
// ever rounded to float32 near the viewer.

uniform mat3 u_rot;          // ECEF direction -> camera axes
uniform mat4 u_proj;
uniform float u_exag;        // vertical exaggeration (live)
uniform vec3 u_inv_axes2;    // (1/a^2, 1/a^2, 1/b^2): gradient of the ellipsoid equation
uniform float u_log_far;     // 1 / log2(1 + far)
uniform float u_depth_bias;  // pulls the wireframe overlay in front of the surface

in vec3 in_pos;              // ellipsoid point (h = 0) relative to the tile centre, metres
in float in_h;               // height above the ellipsoid, metres
in vec2 in_uv;               // texel centre of this node in the tile's textures
in vec3 in_center_rel;       // per draw: tile centre - eye, metres
in vec3 in_center;           // per draw: tile centre, ECEF metres (for directions only)
in float in_layer;           // per draw: slot of the tile in the texture arrays

out vec2 v_uv;
flat out float v_layer;
out vec3 v_up;
out vec3 v_rel;
// Shading factor a displacement hook may set (e.g. darkening the collapsed zone).
out float v_shade;

#define GV_HAS_SHADE 1
float gv_shade = 1.0;
//GV_DISPLACE_DECLS

void main() {
    // The geodetic normal only needs a direction: float32 absolute coordinates are plenty.
    vec3 up = normalize((in_center + in_pos) * u_inv_axes2);
    vec3 rel = in_center_rel + in_pos + up * (in_h * u_exag);
    //GV_DISPLACE_CALL
    vec3 cam = u_rot * rel;
    gl_Position = u_proj * vec4(cam, 1.0);
    // Logarithmic depth (see terrain.frag for why): window depth = log2(1 + w) / log2(1 + far).
    float w = max(-cam.z, 1e-6);
    gl_Position.z = ((2.0 * log2(1.0 + w) * u_log_far - 1.0) - u_depth_bias) * gl_Position.w;
    v_uv = in_uv;
    v_layer = in_layer;
    v_up = up;
    v_rel = rel;
    v_shade = gv_shade;
}
