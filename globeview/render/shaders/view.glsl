// The camera, shared by the vertex shaders: every position reaches them relative to the eye
// (relative_position.glsl), so the view transform is a rotation and the projection.
uniform mat3 u_rot;          // ECEF direction -> camera axes
uniform mat4 u_proj;

// A clip position outside the view volume: a vertex set to it drops its primitive (behind
// the eye, past the horizon).
const vec4 GV_OFFSCREEN = vec4(2.0, 2.0, 2.0, 1.0);
