// Logarithmic depth, written once for every program that depth-tests against the terrain:
// window depth = log2(1 + w) / log2(1 + far) for view depth w (metres).
//
// Relative precision is then the same at every distance (about w * ln(far) / 2^24 with a
// 24-bit buffer: ~1 mm at 100 m, ~20 m at 40 000 km), which one perspective depth range cannot
// give from 100 m to 40 000 km. We chose it over reversed-Z because reversed-Z needs a float
// depth buffer and glClipControl, and neither moderngl's depth textures nor Qt's default
// framebuffer offer a float depth format. It is computed per vertex, not written per
// fragment: on llvmpipe a gl_FragDepth write costs a third of the frame (it disables early
// depth tests); between vertices the depth is interpolated linearly in screen space, which
// is exact at vertices and off by well under a percent of w inside the small triangles the
// LOD keeps. Picking inverts the mapping (picking.py); the CPU sets u_log_far per frame.

uniform float u_log_far;     // 1 / log2(1 + far)

// Normalised device depth (-1 at the eye, 1 at far) of view depth w > 0 (metres). Callers
// subtract their depth bias and multiply by the clip w (the divide by w then undoes it).
float gv_log_depth(float w) {
    return 2.0 * log2(1.0 + w) * u_log_far - 1.0;
}
