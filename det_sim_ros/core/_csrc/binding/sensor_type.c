/*
 * SensorReader(fields): one sample's sensor readings (det_sim_ros.sim.sensors), not physics.
 *
 * Per channel j: the true value t = out[source[j]] (or y0[j] - out[source[j]] where relative),
 * delayed by delay[j] samples (before the first sample of a run: that sample's value), plus
 * offset[row][j] (bias and noise, made per block in numpy), rounded half to even to a multiple
 * of step[j] (0: not rounded; nor a value already whole at float resolution), clipped to
 * [low[j], high[j]]. read() writes the output vector and then the readings into one buffer,
 * which the measured topics' SampleCodec reads. IEEE operations only (no contraction).
 */
#include "binding/binding.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    PyObject_HEAD
    arena mem;                          /* first: the BuiltObject prefix */
    const int64_t *source, *relative, *delay;
    const double *y0, *step, *low, *high;
    int64_t n_channels, n_outputs, rows;
    double *history;                    /* rows x n_channels true values, a ring by sample */
    int64_t first, last;                /* the run's first sample; the last one read (-1) */
} SensorReaderObject;

static int SensorReader_init(SensorReaderObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *src;
    if (built_fields((PyObject *)self, args, kwds, &src) < 0)
        return -1;
    arena *mem = &self->mem;
    Py_ssize_t n;
    if (!(self->source = copy_field(mem, src, "source", 'q', -1, &n))
        || !(self->relative = copy_field(mem, src, "relative", 'q', n, NULL))
        || !(self->delay = copy_field(mem, src, "delay", 'q', n, NULL))
        || !(self->y0 = copy_field(mem, src, "y0", 'd', n, NULL))
        || !(self->step = copy_field(mem, src, "step", 'd', n, NULL))
        || !(self->low = copy_field(mem, src, "low", 'd', n, NULL))
        || !(self->high = copy_field(mem, src, "high", 'd', n, NULL))
        || int_field(src, "n_outputs", &self->n_outputs) < 0)
        return -1;
    self->n_channels = n;
    int64_t max_delay = 0;
    for (int64_t j = 0; j < n; j++) {
        if (self->source[j] < 0 || self->source[j] >= self->n_outputs || self->delay[j] < 0
            || !(self->low[j] <= self->high[j]) || !(self->step[j] >= 0.0)) {
            PyErr_SetString(PyExc_ValueError, "SensorReader: a bad source, delay, step or "
                                              "range");
            return -1;
        }
        if (self->delay[j] > max_delay)
            max_delay = self->delay[j];
    }
    self->rows = max_delay + 1;
    self->history = keep_owned(mem, calloc((size_t)(self->rows * (n > 0 ? n : 1)),
                                           sizeof(double)));
    if (!self->history)
        return -1;
    self->last = -1;
    self->first = 0;
    return 0;
}

/* Write out's values, then the readings of sample k, into vec (see the file comment). */
static void sensor_read(SensorReaderObject *self, const double *out, int64_t k,
                        const double *offset, double *vec)
{
    const int64_t n = self->n_channels, rows = self->rows;
    const int restart = self->last < 0 || k != self->last + 1;
    memcpy(vec, out, (size_t)self->n_outputs * sizeof(double));
    double *now = self->history + (k % rows) * n;
    for (int64_t j = 0; j < n; j++) {
        const double v = out[self->source[j]];
        now[j] = self->relative[j] ? self->y0[j] - v : v;
    }
    if (restart) {
        self->first = k;
        for (int64_t r = 0; r < rows; r++)
            if (self->history + r * n != now)
                memcpy(self->history + r * n, now, (size_t)n * sizeof(double));
    }
    self->last = k;
    for (int64_t j = 0; j < n; j++) {
        int64_t at = k - self->delay[j];
        if (at < self->first)
            at = self->first;
        double r = self->history[(at % rows) * n + j] + offset[j];
        const double step = self->step[j];
        if (step > 0.0) {
            const double levels = r / step;
            if (fabs(levels) < 4503599627370496.0)   /* 2^52: beyond, already whole */
                r = nearbyint(levels) * step;
        }
        r = r < self->low[j] ? self->low[j] : r > self->high[j] ? self->high[j] : r;
        vec[self->n_outputs + j] = r;
    }
}

static PyObject *SensorReader_read(SensorReaderObject *self, PyObject *const *args,
                                   Py_ssize_t n)
{
    if (n != 5) {
        PyErr_SetString(PyExc_TypeError, "read(out, k, offsets, row, vec)");
        return NULL;
    }
    if (built_ready((PyObject *)self) < 0)
        return NULL;
    long long k = PyLong_AsLongLong(args[1]), row = PyLong_AsLongLong(args[3]);
    if ((k == -1 || row == -1) && PyErr_Occurred())
        return NULL;
    const int64_t c = self->n_channels;
    buf out, offsets, vec;
    if (get_buffer(args[0], &out, 'd', -1, 0, "out") < 0)
        return NULL;
    if (get_buffer(args[2], &offsets, 'd', -1, 0, "offsets") < 0) {
        release_buffer(&out);
        return NULL;
    }
    if (get_buffer(args[4], &vec, 'd', self->n_outputs + c, 1, "vec") < 0) {
        release_buffer(&out);
        release_buffer(&offsets);
        return NULL;
    }
    if (k < 0 || out.view.len / 8 < self->n_outputs || row < 0
        || (row + 1) * c > offsets.view.len / 8)
        PyErr_SetString(PyExc_ValueError, "read: a negative sample, a short output vector "
                                          "or a row outside the offsets");
    else
        sensor_read(self, out.view.buf, (int64_t)k, (const double *)offsets.view.buf + row * c,
                    vec.view.buf);
    release_buffer(&out);
    release_buffer(&offsets);
    release_buffer(&vec);
    if (PyErr_Occurred())
        return NULL;
    Py_RETURN_NONE;
}

static PyMethodDef SensorReader_methods[] = {
    {"read", (PyCFunction)(void (*)(void))SensorReader_read, METH_FASTCALL,
     "read(out, k, offsets, row, vec): vec = the output vector out, then the readings of "
     "sample k with offsets[row] (bias and noise per channel); a k that does not follow the "
     "last one starts a run (the delay line over)"},
    {NULL}
};

PyTypeObject SensorReaderType = DS_TYPE(
    SensorReader,
    "SensorReader(fields): one sample's sensor readings, from named fields",
    SensorReaderObject, SensorReader_init, Built_dealloc, SensorReader_methods, NULL);
