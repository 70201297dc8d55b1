// The displacement hook of the terrain vertex shader (docs/plugins.md, "The displacement
// hook"). A tool plugin's displacement_glsl() text replaces this whole file; it must define
//
//     vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 tile_center_rel);
//
// rel: the vertex relative to the eye (ECEF axes, metres); up: the unit ellipsoid normal
// there; h: the height above the ellipsoid (metres, exaggeration applied); tile_center_rel:
// the tile centre relative to the eye. It returns the displaced eye-relative position, and
// may set the float gv_shade (1 = unshaded) when GV_HAS_SHADE is defined. Its uniforms are
// named gv_u_*.
//
// Without a tool: the identity (the compiler removes the call, no pixel changes).
vec3 gv_displace(vec3 rel, vec3 up, float h, vec3 tile_center_rel) {
    return rel;
}
