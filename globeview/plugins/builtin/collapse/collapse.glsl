// The collapse tool's displacement hook: the GLSL twin of `CollapseFrame.forward`
// (geometry.py). `CollapseTool.displacement_glsl()` returns this text (package data) and the
// host puts it in place of the terrain vertex shader's identity hook, shaders/displace.glsl
// (docs/plugins.md, "The displacement hook").
//
// Everything is evaluated relative to the midpoint M or to the eye (see docs/collapse.md,
// "Precision on the GPU"): the vertex's foot point F enters as q = F - M, formed from the
// eye-relative vertex and the float64-computed uniform M - eye, and the result is written as
//
//     rel' = rel + (Rot - I) F + (k - 1) Rot F + h (up' - up)
//
// with (Rot - I) F = R_M (sin(phi) t - (1 - cos phi) m) + sin(phi) n x q - (1 - cos phi) q_perp
// (n . M = 0), k - 1 the ellipsoid re-projection computed from the exact difference of the
// ellipsoid equation (no cancellation), and 1 - cos(phi) = 2 sin^2(phi / 2). No quantity of
// Earth-radius size is added to or subtracted from a small one, except inside terms multiplied
// by phi or by k - 1 (< 3.4e-3), so the rounding error stays far below a metre.
//
// With r = 1 (or no points set) every vertex returns ``rel`` unchanged (pixel-identical).
// If the host defines ``GV_HAS_SHADE`` and a global ``float gv_shade``, vertices inside the
// zone set it below 1 so the fragment shader can darken the collapsed land.

uniform vec3 gv_u_m_rel;   // M - eye (m), formed in float64 on the CPU
uniform vec3 gv_u_m;       // unit geocentric direction of M
uniform vec3 gv_u_t;       // unit axis direction at M, toward B (t = n x m)
uniform vec3 gv_u_n;       // unit normal of the A-B great-circle plane
uniform float gv_u_rm;     // |M| (m)
uniform vec4 gv_u_map;     // psi0 (rad), psi_k (rad), ratio r, unused
uniform vec4 gv_u_ell;     // a^2/b^2, a^2/b^2 - 1, 1/a (1/m), unused

// Rotation angle phi = psi' - psi (rad) of the piecewise-linear along-axis mapping.
float gv_collapse_phi(float psi) {
    const float PI = 3.14159265358979;
    float p0 = gv_u_map.x;
    float pk = gv_u_map.y;
    float r = gv_u_map.z;
    float a = abs(psi);
    float sgn = psi < 0.0 ? -1.0 : 1.0;
    float shift = (1.0 - r) * p0;
    if (a <= p0) return (r - 1.0) * psi;
    if (a <= pk) return -sgn * shift;
    return -sgn * (PI - a) * shift / (PI - pk);
}

vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 tile_center_rel) {
    if (gv_u_map.z >= 1.0) return rel;
    vec3 q = (rel - up * h) - gv_u_m_rel;                 // foot point - M (m)
    float psi = atan(dot(q, gv_u_t), gv_u_rm + dot(q, gv_u_m));
#ifdef GV_HAS_SHADE
    gv_shade = abs(psi) <= gv_u_map.x ? 0.72 : 1.0;
#endif
    float phi = gv_collapse_phi(psi);
    if (phi == 0.0) return rel;
    float sp = sin(phi);
    float s2 = sin(0.5 * phi);
    float omc = 2.0 * s2 * s2;                             // 1 - cos(phi)
    vec3 q_perp = q - gv_u_n * dot(gv_u_n, q);
    // (Rot - I) F, F = M + q, M = R_M m, n . m = 0.
    vec3 dF = gv_u_rm * (sp * gv_u_t - omc * gv_u_m) + sp * cross(gv_u_n, q) - omc * q_perp;
    vec3 F = gv_u_rm * gv_u_m + q;                         // absolute, for small terms only
    vec3 G = F + dF;                                       // Rot F
    // Back onto the ellipsoid along G: k = 1 / sqrt(1 + delta), delta = E(G) - E(F).
    float delta = (dF.z * gv_u_ell.z) * ((2.0 * F.z + dF.z) * gv_u_ell.z) * gv_u_ell.y;
    float sq = sqrt(1.0 + delta);
    float km1 = -delta / (sq * (1.0 + sq));
    vec3 up2 = normalize(vec3(G.xy, G.z * gv_u_ell.x));
    return rel + dF + km1 * G + h * (up2 - up);
}
