/*
 * Marker frames in compiled code (frames.c): the node's I/O path, not physics.
 */
#ifndef DETSIM_WIRE_FRAMES_H
#define DETSIM_WIRE_FRAMES_H

#include <stdint.h>

/* Marker frames (frames.c): the stacked polynomial map of one-coordinate cells. */
typedef struct {
    int64_t n_cells, n_values;             /* cells; drawn values per cell */
    const double *maps;                    /* (cells, values, 4): the 4 coefficients of V */
    const double *thickness_times_height;  /* n d0 l0 per cell (m^2) */
    const int64_t *coordinate;             /* each cell's q in the state vector */
    const int64_t *position;               /* byte offset of each value in the frame */
    const int64_t *stamp_position;         /* byte offset of each header stamp (sec, nanosec) */
    int64_t n_stamps;
    int64_t height, thickness;             /* indices in a cell's values */
    double min_thickness, tolerance;       /* m */
    double *values, *last;                 /* scratch: this frame's and the last written */
} ds_frame_map;

int ds_frame_update(ds_frame_map *f, const double *x, unsigned char *frame, int force,
                    int64_t stamp_ns);

#endif
