// No absolute ECEF coordinate is ever rounded to float32 near the viewer: the camera sits at
// the origin of the space the vertex shaders work in, and positions arrive in one of two ways.
//
// - Relative to the eye, as hi/lo float32 pairs (overlays): a float64 ECEF coordinate split
//   into hi = float32(x) and lo = float32(x - hi) on the CPU, the eye likewise; subtracting
//   the pairs separately keeps millimetres at Earth-radius magnitudes.
// - Relative to a tile centre (terrain): small float32 offsets from the centre, plus the
//   centre relative to the eye, computed per draw in float64 on the CPU.

uniform vec3 u_eye_hi;       // the eye, ECEF metres: float32 high part
uniform vec3 u_eye_lo;       // and the float32 remainder

// Position (ECEF axes, metres) relative to the eye of the point given as a hi/lo pair.
vec3 gv_rel_to_eye(vec3 hi, vec3 lo) {
    return (hi - u_eye_hi) + (lo - u_eye_lo);
}

// Position relative to the eye of a point ``local`` metres from a centre that lies
// ``center_rel`` from the eye (ECEF axes).
vec3 gv_rel_to_centre(vec3 center_rel, vec3 local) {
    return center_rel + local;
}
