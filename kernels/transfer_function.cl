/* The transfer function as the merged knots of exabricks.picture.transfer_function.
 * TransferFunction.merged_knots: RGBA is linear between consecutive knots xs[i]
 * (strictly increasing) and clamps outside [xs[0], xs[n-1]], so this lookup is
 * the exact piecewise-linear function of the preset; eb_table_lookup reads its
 * lookup table instead. */
#pragma once
#include "common.h"

EB_INLINE float4 eb_transfer_function(float value, __global const float *xs,
                                      __global const float4 *rgba, int n)
{
    if (!(value > xs[0]))
        return rgba[0];
    if (value >= xs[n - 1])
        return rgba[n - 1];
    /* Binary search for the last knot lo with xs[lo] <= value (< xs[lo + 1]). */
    int lo = 0, hi = n - 1;
    while (hi - lo > 1) {
        int mid = (lo + hi) >> 1;
        if (xs[mid] <= value)
            lo = mid;
        else
            hi = mid;
    }
    float f = (value - xs[lo]) / (xs[hi] - xs[lo]);
    return mix(rgba[lo], rgba[hi], f);
}

/* The same function from its lookup table (exabricks.picture.transfer_function.lookup_table):
 * t[0] = (x0, K / (x_end - x0), K, 0), then RGBA at K + 1 even nodes; linear
 * between nodes, clamped outside (a NaN value takes node 0, as above). Equal to
 * the knots' function wherever the table interval holds no knot strictly inside
 * (docs/design-rendering.md, "Transfer-function tables"). */
EB_INLINE float4 eb_table_lookup(__global const float4 *t, float value)
{
    float4 h = t[0];
    float x = fmin(fmax((value - h.x) * h.y, 0.0f), h.z);
    int i = min((int)x, (int)h.z - 1);  /* x >= 0: truncation is floor */
    return mix(t[1 + i], t[2 + i], x - (float)i);
}

/* The polynomials of eb_log2_positive and eb_exp2_nonpositive in Horner form,
 * written once for a float and for the vectors of the sample packets (packet.cl). */
#define EB_LOG2_POLY(u)                                                          \
    (1.442695f + (u) * (-0.721347199f + (u) * (0.48091028f + (u) * (-0.360716264f \
     + (u) * (0.287939094f + (u) * (-0.238675687f + (u) * (0.215212268f           \
     + (u) * (-0.208933778f + (u) * 0.129264207f))))))))
#define EB_EXP2_POLY(f)                                                          \
    (1.0f + (f) * (0.693147200f + (f) * (0.240226511f + (f) * (0.0555034061f       \
     + (f) * (0.00961803986f + (f) * (0.00133953101f + (f) * 0.000154653426f))))))

/* log2(x) for a positive normal float x: exponent from the bits, mantissa
 * m in [sqrt(1/2), sqrt(2)) and log2(m) = u P(u) with u = m - 1 and P of
 * degree 8 fitted to log2(1 + u) / u (relative error below 4e-8 on that
 * interval, so log2 of an x near 1 stays accurate relative to its size). */
EB_INLINE float eb_log2_positive(float x)
{
    int bits = as_int(x);
    int e = ((bits >> 23) & 0xff) - 127;
    float m = as_float((bits & 0x007fffff) | 0x3f800000);
    if (m > 1.41421356f) {
        m *= 0.5f;
        e += 1;
    }
    float u = m - 1.0f;
    return (float)e + u * EB_LOG2_POLY(u);
}

/* 2^y for y in [-126, 0]: y = i + f with f in [-1/2, 1/2], a degree-6
 * polynomial for 2^f (least-squares fit, relative error below 1e-8) and 2^i
 * from the bits. */
EB_INLINE float eb_exp2_nonpositive(float y)
{
    float i = rint(y);
    float f = y - i;
    return EB_EXP2_POLY(f) * as_float(((int)i + 127) << 23);
}

/* Opacity of a step of length `len` from the slab opacity `alpha` per
 * `unit_distance` (paper §4.3): 1 - (1 - alpha)^(len / unit_distance), for
 * alpha in (0, 1]. The log2/exp2 pair is inlined as polynomials: PoCL calls
 * its library exp2 and log2 out of line, which made this line a quarter of a
 * frame (docs/benchmarks-render.md, "render (PoCL)"); the result stays within 1e-6
 * of the float64 formula (tests/engine/test_render.py). */
EB_INLINE float eb_opacity_correct(float alpha, float len, float inv_unit_distance)
{
    if (alpha >= 1.0f)
        return 1.0f;
    float y = eb_log2_positive(1.0f - alpha) * (len * inv_unit_distance);
    return 1.0f - eb_exp2_nonpositive(fmax(y, -126.0f));
}
