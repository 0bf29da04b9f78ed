/* The transfer function as the merged knots of exabricks.transfer_function.
 * TransferFunction.merged_knots: RGBA is linear between consecutive knots xs[i]
 * (strictly increasing) and clamps outside [xs[0], xs[n-1]], so this lookup is
 * the exact piecewise-linear function of the preset (no lookup table). */
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

/* Opacity of a step of length `len` from the slab opacity `alpha` per
 * `unit_distance` (paper §4.3): 1 - (1 - alpha)^(len / unit_distance). */
EB_INLINE float eb_opacity_correct(float alpha, float len, float inv_unit_distance)
{
    return 1.0f - exp2(log2(1.0f - alpha) * (len * inv_unit_distance));
}
