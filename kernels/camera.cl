/* The pinhole camera (docs/design-rendering.md, "Camera"): pixel (col, row), row 0 at the
 * top, looks along forward + u du + v dv with u = 2 (col + jx) / W - 1 and
 * v = 1 - 2 (row + jy) / H; (jx, jy) = (0.5, 0.5) is the pixel centre. The host
 * passes the frame of exabricks.picture.camera.Camera.frame unchanged. */
#pragma once
#include "common.h"

/* Unit world-space direction of the ray through sub-pixel (col + jx, row + jy). */
inline float3 eb_camera_direction(float3 forward, float3 du, float3 dv,
                                  int col, int row, int width, int height,
                                  float jx, float jy)
{
    float u = 2.0f * ((float)col + jx) / (float)width - 1.0f;
    float v = 1.0f - 2.0f * ((float)row + jy) / (float)height;
    return normalize(forward + u * du + v * dv);
}

/* World point -> lattice point: (p - origin) / spacing. */
inline float3 eb_world_to_lattice(float3 p_world, float3 origin_world, float3 inv_spacing)
{
    return (p_world - origin_world) * inv_spacing;
}
