// The WGS84 ellipsoid's local frame.
uniform vec3 u_inv_axes2;    // (1/a^2, 1/a^2, 1/b^2): gradient of the ellipsoid equation

// Unit geodetic normal ("up") at ECEF point p: a direction only, so float32 absolute
// coordinates are plenty.
vec3 gv_ellipsoid_up(vec3 p) {
    return normalize(p * u_inv_axes2);
}

// Unit east and north at a point with unit normal up (the tiny x offset keeps east defined
// at the poles).
void gv_east_north(vec3 up, out vec3 east, out vec3 north) {
    east = normalize(cross(vec3(0.0, 0.0, 1.0), up) + vec3(1e-9, 0.0, 0.0));
    north = cross(up, east);
}
