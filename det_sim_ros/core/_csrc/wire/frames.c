/*
 * Marker frames of one-coordinate cells (det_sim_ros/ros/markers.py, MarkerFrames): every drawn
 * value of a cell is a polynomial in its coordinate q, V = P0 + P1 q + P2 q^2 + P3 q^4, and
 * the DET's drawn thickness is n d0 l0 / height. The node builds a frame every few dozen
 * control samples, with caches the samples' DDS work has cooled, where numpy's many small
 * calls pay their first touch each time; here a frame is one call (its cost:
 * docs/performance.md, 'Markers'). The numpy version (MarkerFrames.values) stays the reference
 * the tests hold this code to.
 */
#include <math.h>
#include <string.h>

#include "wire/frames.h"
#include "wire/endian.h"

/*
 * The frame's values at state x into f->values; unless ``force``, 0 when no value moved by
 * more than f->tolerance since the last frame written here. Otherwise the values and the stamp
 * are written into ``frame`` (the serialized MarkerArray) and remembered, and 1 is returned.
 */
int ds_frame_update(ds_frame_map *f, const double *x, unsigned char *frame, int force,
                    int64_t stamp_ns)
{
    const int64_t nv = f->n_values, n = f->n_cells * nv;
    for (int64_t c = 0; c < f->n_cells; c++) {
        const double q = x[f->coordinate[c]], q2 = q * q, q4 = q2 * q2;
        const double *P = f->maps + c * nv * 4;
        double *v = f->values + c * nv;
        for (int64_t i = 0; i < nv; i++)
            v[i] = P[4 * i] + P[4 * i + 1] * q + P[4 * i + 2] * q2 + P[4 * i + 3] * q4;
        const double thick = f->thickness_times_height[c] / v[f->height];
        v[f->thickness] = thick > f->min_thickness ? thick : f->min_thickness;
    }
    if (!force) {
        double shift = 0.0;
        for (int64_t i = 0; i < n; i++) {
            const double d = fabs(f->values[i] - f->last[i]);
            if (d > shift)
                shift = d;
        }
        if (!(shift > f->tolerance))
            return 0;
    }
    for (int64_t i = 0; i < n; i++)
        ds_put_f64(frame + f->position[i], f->values[i]);
    memcpy(f->last, f->values, (size_t)n * sizeof(double));
    for (int64_t k = 0; k < f->n_stamps; k++)
        ds_put_stamp(frame + f->stamp_position[k], stamp_ns);
    return 1;
}
