/*
 * Python binding of the compiled kernel: det_sim_ros.core._ckernel.
 *
 * Model(arrays)   reads the named fields of det_sim_ros.physics.model.ModelArrays (attribute by
 *                 attribute: never positional) and keeps its own copy in C structs.
 * Stepper(...)    a method table, transient settings and step-count control for a Model.
 * FrameMap(fields) marker frames of one-coordinate cells (frames.c), from named fields.
 * SampleCodec(fields) one sample's output messages (wire.c), from named fields.
 * pack_records(...)   consecutive samples' MCAP Message records (wire.c).
 *
 * Arrays cross by the buffer protocol (C-contiguous float64 / int64): no numpy C API, so the
 * module builds with only a C compiler and Python's headers and works with any numpy.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "detsim.h"

/* ---------------------------------------------------------------- buffers */

typedef struct {
    Py_buffer view;
    int held;
} buf;

static void release(buf *b)
{
    if (b->held)
        PyBuffer_Release(&b->view);
    b->held = 0;
}

/* A C-contiguous float64 (kind 'd') or int64 (kind 'q') buffer of ``n`` items (n < 0: any). */
static int get_buffer(PyObject *obj, buf *b, char kind, Py_ssize_t n, int writable,
                      const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    b->held = 0;
    if (PyObject_GetBuffer(obj, &b->view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s: expected a %sC-contiguous %s array", what,
                     writable ? "writable " : "", kind == 'd' ? "float64" : "int64");
        return -1;
    }
    b->held = 1;
    const char *f = b->view.format ? b->view.format : "B";
    if (*f == '<' || *f == '=' || *f == '@')
        f++;
    int ok = b->view.itemsize == 8 && f[1] == '\0'
             && (kind == 'd' ? f[0] == 'd' : (f[0] == 'q' || f[0] == 'l'));
    if (!ok) {
        PyErr_Format(PyExc_TypeError, "%s: expected %s items (got format '%s')", what,
                     kind == 'd' ? "float64" : "int64", b->view.format);
        release(b);
        return -1;
    }
    if (n >= 0 && b->view.len / 8 != n) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd values, got %zd", what, n,
                     b->view.len / 8);
        release(b);
        return -1;
    }
    return 0;
}

/* What one argument must be: item kind ('d' float64, 'q' int64), count (< 0: any), writable. */
typedef struct {
    char kind;
    Py_ssize_t n;
    int writable;
    const char *name;
} spec;

/* Acquire args[0..count-1] as ``specs`` say, into b; on failure none is held. */
static int get_buffers(PyObject *const *args, const spec *specs, int count, buf *b)
{
    for (int i = 0; i < count; i++) {
        if (get_buffer(args[i], &b[i], specs[i].kind, specs[i].n, specs[i].writable,
                       specs[i].name) < 0) {
            while (i--)
                release(&b[i]);
            return -1;
        }
    }
    return 0;
}

static void release_buffers(buf *b, int count)
{
    for (int i = 0; i < count; i++)
        release(&b[i]);
}

/* ---------------------------------------------------------------- owned copies */

/* The memory an object owns (its copies of the named fields), freed with it. */
typedef struct {
    void *p[48];
    int n;
} arena;

static void *keep(arena *a, void *p)
{
    if (p)
        a->p[a->n++] = p;
    return p;
}

static void free_arena(arena *a)
{
    for (int i = 0; i < a->n; i++)
        free(a->p[i]);
    a->n = 0;
}

/* Copy the named array field ``name`` of ``src`` (n items, n < 0: any) into owned memory. */
static void *copy_field(arena *mem, PyObject *src, const char *name, char kind,
                        Py_ssize_t n, Py_ssize_t *got)
{
    PyObject *obj = PyObject_GetAttrString(src, name);
    if (!obj)
        return NULL;
    buf b;
    if (get_buffer(obj, &b, kind, n, 0, name) < 0) {
        Py_DECREF(obj);
        return NULL;
    }
    Py_ssize_t len = b.view.len;
    void *p = keep(mem, malloc(len > 0 ? (size_t)len : 8));
    if (!p) {
        PyErr_NoMemory();
    } else {
        memcpy(p, b.view.buf, (size_t)len);
        if (got)
            *got = len / 8;
    }
    release(&b);
    Py_DECREF(obj);
    return p;
}

static int int_field(PyObject *src, const char *name, int64_t *out)
{
    PyObject *obj = PyObject_GetAttrString(src, name);
    if (!obj)
        return -1;
    long long v = PyLong_AsLongLong(obj);
    Py_DECREF(obj);
    if (v == -1 && PyErr_Occurred())
        return -1;
    *out = (int64_t)v;
    return 0;
}

static int float_field(PyObject *src, const char *name, double *out)
{
    PyObject *obj = PyObject_GetAttrString(src, name);
    if (!obj)
        return -1;
    double v = PyFloat_AsDouble(obj);
    Py_DECREF(obj);
    if (v == -1.0 && PyErr_Occurred())
        return -1;
    *out = v;
    return 0;
}

/* ---------------------------------------------------------------- Model */

typedef struct {
    PyObject_HEAD
    ds_model m;
    ds_work w;
    arena mem;
} ModelObject;

static void Model_dealloc(ModelObject *self)
{
    ds_work_free(&self->w);
    free_arena(&self->mem);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Model_init(ModelObject *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"arrays", NULL};
    PyObject *src;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O", kwlist, &src))
        return -1;
    if (self->mem.n)
        return 0;   /* already built */
    arena *mem = &self->mem;
    ds_model *m = &self->m;
    memset(m, 0, sizeof(*m));
    int64_t creep, rc, power;
    if (int_field(src, "n_q", &m->n_q) < 0 || int_field(src, "n_cells", &m->n_cells) < 0
        || int_field(src, "n_state", &m->n_state) < 0 || int_field(src, "r_max", &m->r_max) < 0
        || int_field(src, "creep", &creep) < 0 || int_field(src, "rc_source", &rc) < 0
        || int_field(src, "power_monitor", &power) < 0)
        return -1;
    m->creep = (int)creep;
    m->rc_source = (int)rc;
    m->power = (int)power;
    const int64_t nq = m->n_q, nc = m->n_cells, R = m->r_max;
    if (nq < 1 || nc < 1 || R < 1) {
        PyErr_SetString(PyExc_ValueError, "a model needs at least one cell and coordinate");
        return -1;
    }
    m->i_eps = 2 * nq;
    m->i_qp = m->i_eps + nc * m->creep;
    m->i_power = m->i_qp + nc * m->rc_source;
    if (m->n_state != m->i_power + 2 * m->power) {
        PyErr_SetString(PyExc_ValueError, "n_state does not match the state layout");
        return -1;
    }
    Py_ssize_t n_nodes, n_mi, n_groups1, n_p;
    int64_t *cell_q = copy_field(mem, src, "cell_q", 'q', nc + 1, NULL);
    int64_t *cell_g = cell_q ? copy_field(mem, src, "cell_g", 'q', nc + 1, NULL) : NULL;
    int64_t *cell_group = cell_g ? copy_field(mem, src, "cell_group", 'q', nc, NULL) : NULL;
    int64_t *kin = cell_group ? copy_field(mem, src, "kinematics", 'q', nc, NULL) : NULL;
    if (!kin)
        return -1;
    n_nodes = cell_g[nc];
    if (!(m->W = copy_field(mem, src, "W", 'd', n_nodes, NULL))
        || !(m->B1 = copy_field(mem, src, "B1", 'd', n_nodes * R, NULL))
        || !(m->B2 = copy_field(mem, src, "B2", 'd', n_nodes * R, NULL))
        || !(m->Mb = copy_field(mem, src, "Mb", 'd', nq * R, NULL))
        || !(m->K = copy_field(mem, src, "K", 'd', nq * R, NULL))
        || !(m->D = copy_field(mem, src, "D", 'd', nq * R, NULL))
        || !(m->ref = copy_field(mem, src, "ref", 'd', nq, NULL))
        || !(m->mi_val = copy_field(mem, src, "mi_val", 'd', -1, &n_mi))
        || !(m->mi_row = copy_field(mem, src, "mi_row", 'q', n_mi, NULL))
        || !(m->mi_col = copy_field(mem, src, "mi_col", 'q', n_mi, NULL))
        || !(m->group_q = copy_field(mem, src, "group_q", 'q', -1, &n_groups1))
        || !(m->P = copy_field(mem, src, "P", 'd', -1, &n_p)))
        return -1;
    m->n_nodes = n_nodes;
    m->n_mi = n_mi;
    m->n_groups = n_groups1 - 1;
    m->n_structure = n_p / nc;
    if (m->n_groups < 1 || m->group_q[m->n_groups] != nq || n_p % nc) {
        PyErr_SetString(PyExc_ValueError, "inconsistent group offsets or structure map");
        return -1;
    }
    static const char *cell_names[] = {"length", "EI", "c2", "c4", "e4"};
    static const char *det_names[] = {"l0", "VY", "C0", "volume", "E_M", "eta_M", "eta_v",
                                      "Rs", "Rp"};
    double *cell_f[5], *det_f[9];
    for (int i = 0; i < 5; i++)
        if (!(cell_f[i] = copy_field(mem, src, cell_names[i], 'd', nc, NULL)))
            return -1;
    for (int i = 0; i < 9; i++)
        if (!(det_f[i] = copy_field(mem, src, det_names[i], 'd', nc, NULL)))
            return -1;
    m->cell = keep(mem, calloc((size_t)nc, sizeof(ds_cell)));
    m->det = keep(mem, calloc((size_t)nc, sizeof(ds_det)));
    if (!m->cell || !m->det) {
        PyErr_NoMemory();
        return -1;
    }
    m->mass_block = 1;
    for (int64_t g = 0; g < m->n_groups; g++)
        if (m->group_q[g + 1] - m->group_q[g] > m->mass_block)
            m->mass_block = m->group_q[g + 1] - m->group_q[g];
    for (int64_t c = 0; c < nc; c++) {
        ds_cell *cell = &m->cell[c];
        cell->q0 = cell_q[c];
        cell->nr = cell_q[c + 1] - cell_q[c];
        cell->g0 = cell_g[c];
        cell->g1 = cell_g[c + 1];
        cell->group = cell_group[c];
        if (cell->nr < 1 || cell->nr > R || cell->group < 0 || cell->group >= m->n_groups
            || kin[c] < KIN_PAPER || kin[c] > KIN_EXACT) {
            PyErr_Format(PyExc_ValueError, "cell %lld: inconsistent layout", (long long)c);
            return -1;
        }
        cell->mass_col = cell->q0 - m->group_q[cell->group];
        cell->kinematics = (int)kin[c];
        cell->kappa = kin[c] == KIN_CONSISTENT ? 1.0 : 0.0;
        cell->length = cell_f[0][c];
        cell->EI = cell_f[1][c];
        cell->c2 = cell_f[2][c];
        cell->c4 = cell_f[3][c];
        cell->e4 = cell_f[4][c];
        ds_det *d = &m->det[c];
        d->l0 = det_f[0][c];
        d->VY = det_f[1][c];
        d->C0 = det_f[2][c];
        d->volume = det_f[3][c];
        d->E_M = det_f[4][c];
        d->eta_M = det_f[5][c];
        d->eta_v = det_f[6][c];
        d->Rs = det_f[7][c];
        d->Rp = det_f[8][c];
        d->inv_l0 = 1.0 / d->l0;
        d->inv_C0 = 1.0 / d->C0;
        d->inv_Rs = 1.0 / d->Rs;
        d->inv_Rp = 1.0 / d->Rp;
        d->share = d->Rp / (d->Rs + d->Rp);
        d->relax_M = d->eta_M > 0.0 ? d->E_M / d->eta_M : 0.0;
    }
    for (int64_t e = 0; e < n_mi; e++) {
        if (m->mi_row[e] < 0 || m->mi_row[e] >= nc || m->mi_col[e] < 0 || m->mi_col[e] >= nc
            || m->cell[m->mi_row[e]].group != m->cell[m->mi_col[e]].group) {
            PyErr_SetString(PyExc_ValueError, "interface mass couples cells of two groups");
            return -1;
        }
    }
    m->one_term = nc == 1 && m->cell[0].nr == 1 && m->cell[0].kinematics != KIN_EXACT;
    if (ds_work_init(&self->w, m) < 0) {
        PyErr_NoMemory();
        return -1;
    }
    return 0;
}

#define X_SPEC(m, w) {'d', (m)->n_state, (w), "x"}
#define U_SPEC(m, name) {'d', (m)->n_cells, 0, (name)}

static PyObject *Model_rhs(ModelObject *self, PyObject *const *args, Py_ssize_t n)
{
    if (n < 3 || n > 4) {
        PyErr_SetString(PyExc_TypeError, "rhs(x, u, dx[, quasi_static])");
        return NULL;
    }
    const ds_model *m = &self->m;
    const spec specs[] = {X_SPEC(m, 0), U_SPEC(m, "u"), {'d', m->n_state, 1, "dx"}};
    buf b[3];
    if (get_buffers(args, specs, 3, b) < 0)
        return NULL;
    int qs = n == 4 ? PyObject_IsTrue(args[3]) : 0;
    int status = ds_rhs(m, b[0].view.buf, b[1].view.buf, b[2].view.buf, &self->w, qs > 0);
    release_buffers(b, 3);
    return Py_BuildValue("(idd)", status, self->w.p_in, self->w.p_diss);
}

static PyObject *Model_outputs(ModelObject *self, PyObject *const *args, Py_ssize_t n)
{
    if (n != 3) {
        PyErr_SetString(PyExc_TypeError, "outputs(x, u, out)");
        return NULL;
    }
    const ds_model *m = &self->m;
    const spec specs[] = {X_SPEC(m, 0), U_SPEC(m, "u"), {'d', ds_n_outputs(m), 1, "out"}};
    buf b[3];
    if (get_buffers(args, specs, 3, b) < 0)
        return NULL;
    int status = ds_outputs(m, b[0].view.buf, b[1].view.buf, b[2].view.buf, &self->w);
    release_buffers(b, 3);
    return PyLong_FromLong(status);
}

static PyObject *Model_stiff_rates(ModelObject *self, PyObject *const *args, Py_ssize_t n)
{
    if (n != 2) {
        PyErr_SetString(PyExc_TypeError, "stiff_rates(x, L)");
        return NULL;
    }
    const ds_model *m = &self->m;
    const spec specs[] = {X_SPEC(m, 0), {'d', m->n_state, 1, "L"}};
    buf b[2];
    if (get_buffers(args, specs, 2, b) < 0)
        return NULL;
    int status = ds_stiff_rates(m, b[0].view.buf, b[1].view.buf, &self->w, 1);
    release_buffers(b, 2);
    return PyLong_FromLong(status);
}

static PyObject *Model_book_input_jump(ModelObject *self, PyObject *const *args, Py_ssize_t n)
{
    if (n != 3) {
        PyErr_SetString(PyExc_TypeError, "book_input_jump(x, u_old, u_new)");
        return NULL;
    }
    const ds_model *m = &self->m;
    const spec specs[] = {X_SPEC(m, 1), U_SPEC(m, "u"), U_SPEC(m, "u_new")};
    buf b[3];
    if (get_buffers(args, specs, 3, b) < 0)
        return NULL;
    ds_book_input_jump(m, b[0].view.buf, b[1].view.buf, b[2].view.buf, &self->w);
    release_buffers(b, 3);
    Py_RETURN_NONE;
}

static PyObject *Model_get_int(ModelObject *self, void *which)
{
    switch ((intptr_t)which) {
    case 0: return PyLong_FromLongLong(self->m.n_state);
    case 1: return PyLong_FromLongLong(ds_n_outputs(&self->m));
    case 2: return PyLong_FromLongLong(self->m.mass_block);
    default: return PyLong_FromLongLong(self->m.n_groups);
    }
}

static PyMethodDef Model_methods[] = {
    {"rhs", (PyCFunction)(void (*)(void))Model_rhs, METH_FASTCALL,
     "rhs(x, u, dx[, quasi_static]) -> (status, P_in, P_diss): dx = f(x, u)"},
    {"outputs", (PyCFunction)(void (*)(void))Model_outputs, METH_FASTCALL,
     "outputs(x, u, out) -> status: the named outputs into out"},
    {"stiff_rates", (PyCFunction)(void (*)(void))Model_stiff_rates, METH_FASTCALL,
     "stiff_rates(x, L) -> status: diagonal stiff part (1/s) at the charge states"},
    {"book_input_jump", (PyCFunction)(void (*)(void))Model_book_input_jump, METH_FASTCALL,
     "book_input_jump(x, u_old, u_new): ideal source + monitor: book the recharge"},
    {NULL}
};

static PyGetSetDef Model_getset[] = {
    {"n_state", (getter)Model_get_int, NULL, "states", (void *)0},
    {"n_outputs", (getter)Model_get_int, NULL, "outputs", (void *)1},
    {"mass_block", (getter)Model_get_int, NULL, "largest coupled group's coordinates",
     (void *)2},
    {"n_groups", (getter)Model_get_int, NULL, "independent coupled groups", (void *)3},
    {NULL}
};

static PyTypeObject ModelType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "det_sim_ros.core._ckernel.Model",
    .tp_doc = "Model(arrays): the compiled model, built from ModelArrays' named fields",
    .tp_basicsize = sizeof(ModelObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Model_init,
    .tp_dealloc = (destructor)Model_dealloc,
    .tp_methods = Model_methods,
    .tp_getset = Model_getset,
};

/* ---------------------------------------------------------------- Stepper */

typedef struct {
    PyObject_HEAD
    ModelObject *model;
    ds_stepper st;
    ds_work out_work;   /* outputs after a period: the stepper's own (run() releases the GIL) */
    int ready;
} StepperObject;

static void Stepper_dealloc(StepperObject *self)
{
    if (self->ready) {
        ds_stepper_free(&self->st);
        ds_work_free(&self->out_work);
    }
    Py_XDECREF(self->model);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int Stepper_init(StepperObject *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"model", "c", "terms", "embedded", "error_weights", "dt",
                             "z_tol", "fine", "substeps", "tolerance", "min_substeps",
                             "max_substeps", "exponent", "jump_ref", NULL};
    PyObject *model, *c, *terms, *embedded, *weights;
    double dt, z_tol, fine, tol, exponent, jump_ref = 0.0;
    long long n0, n_min, n_max;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O!OOOOdddLdLLd|d", kwlist, &ModelType, &model,
                                     &c, &terms, &embedded, &weights, &dt, &z_tol, &fine, &n0,
                                     &tol, &n_min, &n_max, &exponent, &jump_ref))
        return -1;
    if (self->ready) {
        PyErr_SetString(PyExc_RuntimeError, "Stepper already initialised");
        return -1;
    }
    if (!(dt > 0.0) || n0 < 1 || n_min < 1 || n_max < n_min || !(exponent > 0.0)
        || !(jump_ref >= 0.0 && jump_ref < INFINITY)) {
        PyErr_SetString(PyExc_ValueError, "Stepper: need dt > 0, 1 <= min <= max substeps, "
                                          "a finite jump_ref >= 0");
        return -1;
    }
    ModelObject *mo = (ModelObject *)model;
    PyObject *const tables[] = {c, terms, embedded, weights};
    const spec specs[] = {{'d', -1, 0, "c"}, {'d', -1, 0, "terms"}, {'d', -1, 0, "embedded"},
                          {'d', mo->m.n_state, 0, "error_weights"}};
    buf b[4];
    if (get_buffers(tables, specs, 4, b) < 0)
        return -1;
    const Py_buffer bc = b[0].view, bt = b[1].view, be = b[2].view, bw = b[3].view;
    const Py_ssize_t s = bc.len / 8;
    int rc = -1;
    const Py_ssize_t nt = bt.len / 40;
    const double *tv = bt.buf;
    int valid = s >= 1 && bt.len % 40 == 0;
    for (Py_ssize_t t = 0; valid && t < nt; t++) {
        const double *row = tv + 5 * t;
        valid = row[0] >= 0 && row[0] <= s && row[1] >= 0 && row[1] < s && row[2] >= -1
                && row[2] < 60 && (t == 0 || row[0] >= tv[5 * (t - 1)]);
    }
    if (!valid) {
        PyErr_SetString(PyExc_ValueError, "method table: terms must be rows (i, j, k, c, w) "
                                          "sorted by stage row i");
    } else if (ds_method_init(&self->st.method, bc.buf, s, tv, nt, be.buf, be.len / 8) < 0) {
        PyErr_NoMemory();
    } else {
        ds_control ctl = {n0, n_min, n_max, tol, exponent};
        self->st.jump_ref = jump_ref;
        if (ds_stepper_init(&self->st, &mo->m, dt, z_tol, fine, &ctl, bw.buf) < 0
            || ds_work_init(&self->out_work, &mo->m) < 0) {
            ds_stepper_free(&self->st);
            PyErr_NoMemory();
        } else {
            Py_INCREF(model);
            self->model = mo;
            self->ready = 1;
            rc = 0;
        }
    }
    release_buffers(b, 4);
    return rc;
}

#define NEED_READY(self)                                                          \
    if (!(self)->ready) {                                                         \
        PyErr_SetString(PyExc_RuntimeError, "Stepper not initialised");           \
        return NULL;                                                              \
    }

static PyObject *Stepper_advance(StepperObject *self, PyObject *const *args, Py_ssize_t n)
{
    NEED_READY(self);
    if (n < 4 || n > 5) {
        PyErr_SetString(PyExc_TypeError, "advance(x, u, h, n_steps[, growth])");
        return NULL;
    }
    if (self->st.n_groups != 1) {
        PyErr_SetString(PyExc_ValueError, "advance() steps a model of one coupled group; "
                                          "use period() for independent groups");
        return NULL;
    }
    double h = PyFloat_AsDouble(args[2]);
    long long steps = PyLong_AsLongLong(args[3]);
    double growth = n == 5 ? PyFloat_AsDouble(args[4]) : 1.0;
    if (PyErr_Occurred())
        return NULL;
    const ds_model *m = &self->model->m;
    const spec specs[] = {X_SPEC(m, 1), U_SPEC(m, "u")};
    buf b[2];
    if (get_buffers(args, specs, 2, b) < 0)
        return NULL;
    int status = ds_advance(&self->st, &self->st.group[0], b[0].view.buf, b[1].view.buf, h,
                            steps, growth);
    release_buffers(b, 2);
    return PyLong_FromLong(status);
}

/* period(x, u_old, u, out) -> status: one control period, then the outputs into out. */
static PyObject *Stepper_period(StepperObject *self, PyObject *const *args, Py_ssize_t n)
{
    NEED_READY(self);
    if (n != 4) {
        PyErr_SetString(PyExc_TypeError, "period(x, u_old, u, out)");
        return NULL;
    }
    const ds_model *m = &self->model->m;
    const spec specs[] = {X_SPEC(m, 1), U_SPEC(m, "u_old"), U_SPEC(m, "u"),
                          {'d', ds_n_outputs(m), 1, "out"}};
    buf b[4];
    if (get_buffers(args, specs, 4, b) < 0)
        return NULL;
    double *x = b[0].view.buf, *u = b[2].view.buf;
    const double *u_old = b[1].view.buf;
    int status;
    if (self->st.n_groups > 1) {   /* batches take long enough to let other threads run */
        Py_BEGIN_ALLOW_THREADS
        status = ds_period(&self->st, x, u_old, u);
        Py_END_ALLOW_THREADS
    } else {
        status = ds_period(&self->st, x, u_old, u);
    }
    if (status == DS_OK)
        status = ds_outputs(m, x, u, b[3].view.buf, &self->out_work);
    release_buffers(b, 4);
    return PyLong_FromLong(status);
}

/*
 * run(x, u_held, u_last, U, X, Y) -> (status, periods completed): many periods in one call.
 * Period k holds U[k]; X[k + 1] and Y[k + 1] receive the state and outputs after it; u_held is
 * the input held now (already booked), u_last the one the last period ran with. x is left at
 * the last good state. The GIL is released for the whole run.
 */
static PyObject *Stepper_run(StepperObject *self, PyObject *const *args, Py_ssize_t n)
{
    NEED_READY(self);
    if (n != 6) {
        PyErr_SetString(PyExc_TypeError, "run(x, u_held, u_last, U, X, Y)");
        return NULL;
    }
    ModelObject *mo = self->model;
    const ds_model *m = &mo->m;
    const int64_t nx = m->n_state, nu = m->n_cells, ny = ds_n_outputs(m);
    const spec inputs[] = {{'d', nx, 1, "x"}, {'d', nu, 0, "u_held"}, {'d', nu, 0, "u_last"},
                           {'d', -1, 0, "U"}};
    buf b[6];
    if (get_buffers(args, inputs, 4, b) < 0)
        return NULL;
    const Py_ssize_t n_periods = b[3].view.len / 8 / nu;
    if (n_periods * nu * 8 != b[3].view.len) {
        PyErr_SetString(PyExc_ValueError, "U: shape (n_periods, n_inputs)");
        release_buffers(b, 4);
        return NULL;
    }
    const spec outputs[] = {{'d', (n_periods + 1) * nx, 1, "X"},
                            {'d', (n_periods + 1) * ny, 1, "Y"}};
    if (get_buffers(args + 4, outputs, 2, b + 4) < 0) {
        release_buffers(b, 4);
        return NULL;
    }
    int status;
    int64_t k;
    Py_BEGIN_ALLOW_THREADS
    status = ds_run(&self->st, &self->out_work, b[0].view.buf, b[1].view.buf, b[2].view.buf,
                    b[3].view.buf, n_periods, b[4].view.buf, b[5].view.buf, &k);
    Py_END_ALLOW_THREADS
    release_buffers(b, 6);
    return Py_BuildValue("(iL)", status, (long long)k);
}

static PyObject *Stepper_reset_control(StepperObject *self, PyObject *unused)
{
    NEED_READY(self);
    ds_reset_control(&self->st);
    Py_RETURN_NONE;
}

static PyObject *Stepper_group_substeps(StepperObject *self, PyObject *unused)
{
    NEED_READY(self);
    PyObject *list = PyList_New(self->st.n_groups);
    for (int64_t g = 0; list && g < self->st.n_groups; g++)
        PyList_SET_ITEM(list, g, PyLong_FromLongLong(self->st.group[g].ctl.n));
    return list;
}

static PyObject *Stepper_get(StepperObject *self, void *which)
{
    NEED_READY(self);
    const ds_stepper *st = &self->st;
    double total = 0.0, best = 0.0;
    int64_t n = 0;
    for (int64_t g = 0; g < st->n_groups; g++) {
        total += st->group[g].steps;
        if (st->group[g].est > best)
            best = st->group[g].est;
        if (st->group[g].ctl.n > n)
            n = st->group[g].ctl.n;
    }
    switch ((intptr_t)which) {
    case 0: return PyLong_FromLongLong(n);
    case 1: return PyFloat_FromDouble(total);
    case 2: return PyFloat_FromDouble(best);
    case 3: return PyLong_FromLongLong(st->n_groups);
    case 4: return PyLong_FromLong(st->threads);
    case 5: return PyLong_FromLongLong(st->group[0].ctl_initial.n_min);
    case 6: return PyLong_FromLongLong(st->group[0].ctl_initial.n_max);
    case 7: return PyFloat_FromDouble(st->group[0].ctl_initial.tol);
    default:
#ifdef _OPENMP
        Py_RETURN_TRUE;
#else
        Py_RETURN_FALSE;
#endif
    }
}

static int Stepper_set(StepperObject *self, PyObject *value, void *which)
{
    if (!self->ready || !value) {
        PyErr_SetString(PyExc_AttributeError, "cannot delete or set before init");
        return -1;
    }
    ds_stepper *st = &self->st;
    if ((intptr_t)which == 0) {   /* substeps: the count every group starts its next period with */
        long long n = PyLong_AsLongLong(value);
        if (n == -1 && PyErr_Occurred())
            return -1;
        if (n < 1) {
            PyErr_SetString(PyExc_ValueError, "substeps must be >= 1");
            return -1;
        }
        for (int64_t g = 0; g < st->n_groups; g++)
            st->group[g].ctl.n = n;
        return 0;
    }
    if ((intptr_t)which == 2) {   /* estimate: reset before a measurement */
        double e = PyFloat_AsDouble(value);
        if (PyErr_Occurred())
            return -1;
        for (int64_t g = 0; g < st->n_groups; g++)
            st->group[g].est = e;
        return 0;
    }
    long t = PyLong_AsLong(value);
    if (t == -1 && PyErr_Occurred())
        return -1;
    if (t < 1 || t > 256) {
        PyErr_SetString(PyExc_ValueError, "threads must be in [1, 256]");
        return -1;
    }
    st->threads = (int)t;
    return 0;
}

static PyMethodDef Stepper_methods[] = {
    {"advance", (PyCFunction)(void (*)(void))Stepper_advance, METH_FASTCALL,
     "advance(x, u, h, n_steps[, growth]) -> status: n_steps fixed steps (one group)"},
    {"period", (PyCFunction)(void (*)(void))Stepper_period, METH_FASTCALL,
     "period(x, u_old, u, out) -> status: one control period, then the outputs"},
    {"run", (PyCFunction)(void (*)(void))Stepper_run, METH_FASTCALL,
     "run(x, u_held, u_last, U, X, Y) -> (status, periods): many periods, GIL released"},
    {"reset_control", (PyCFunction)Stepper_reset_control, METH_NOARGS,
     "step counts and error estimates back to their initial values"},
    {"group_substeps", (PyCFunction)Stepper_group_substeps, METH_NOARGS,
     "the step count of each coupled group's next period"},
    {NULL}
};

static PyGetSetDef Stepper_getset[] = {
    {"substeps", (getter)Stepper_get, (setter)Stepper_set,
     "steps the next period starts with (largest over the groups; set: every group)",
     (void *)0},
    {"steps_taken", (getter)Stepper_get, NULL, "internal steps taken, all groups", (void *)1},
    {"estimate", (getter)Stepper_get, (setter)Stepper_set,
     "largest embedded error estimate since it was last set", (void *)2},
    {"n_groups", (getter)Stepper_get, NULL, "independent coupled groups", (void *)3},
    {"threads", (getter)Stepper_get, (setter)Stepper_set,
     "threads that step independent groups (results do not depend on it)", (void *)4},
    {"min_substeps", (getter)Stepper_get, NULL, "fewest steps per period", (void *)5},
    {"max_substeps", (getter)Stepper_get, NULL, "most steps per period", (void *)6},
    {"tolerance", (getter)Stepper_get, NULL, "local tolerance (0: fixed count)", (void *)7},
    {"openmp", (getter)Stepper_get, NULL, "built with OpenMP (threads > 1 possible)",
     (void *)8},
    {NULL}
};

static PyTypeObject StepperType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "det_sim_ros.core._ckernel.Stepper",
    .tp_doc = "Stepper(model, c, terms, embedded, error_weights, dt, z_tol, fine, substeps, "
              "tolerance, min_substeps, max_substeps, exponent[, jump_ref])",
    .tp_basicsize = sizeof(StepperObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Stepper_init,
    .tp_dealloc = (destructor)Stepper_dealloc,
    .tp_methods = Stepper_methods,
    .tp_getset = Stepper_getset,
};

/* ---------------------------------------------------------------- types built from fields */

/* FrameMap and SampleCodec are built once from an object's named fields into owned copies:
 * their structs start with this prefix, so one dealloc and one set of checks serve both. */
typedef struct {
    PyObject_HEAD
    arena mem;
} BuiltObject;

static void Built_dealloc(PyObject *self)
{
    free_arena(&((BuiltObject *)self)->mem);
    Py_TYPE(self)->tp_free(self);
}

/* The ``fields`` argument of __init__ into *src; refuses a second build (-1, error set). */
static int built_fields(PyObject *self, PyObject *args, PyObject *kwds, PyObject **src)
{
    static char *kwlist[] = {"fields", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O", kwlist, src))
        return -1;
    if (((BuiltObject *)self)->mem.n) {
        PyErr_Format(PyExc_RuntimeError, "%s is already built", Py_TYPE(self)->tp_name);
        return -1;
    }
    return 0;
}

/* 0 when built, else -1 with the error set (a method called before a successful __init__). */
static int built_ready(PyObject *self)
{
    if (((BuiltObject *)self)->mem.n)
        return 0;
    PyErr_Format(PyExc_RuntimeError, "%s was not built", Py_TYPE(self)->tp_name);
    return -1;
}

/* ---------------------------------------------------------------- FrameMap */

typedef struct {
    PyObject_HEAD
    arena mem;                          /* first: the BuiltObject prefix */
    ds_frame_map f;
    Py_ssize_t frame_size;
} FrameMapObject;

static int FrameMap_init(FrameMapObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *src;
    if (built_fields((PyObject *)self, args, kwds, &src) < 0)
        return -1;
    ds_frame_map *f = &self->f;
    arena *mem = &self->mem;
    int64_t frame_size;
    Py_ssize_t n_cells, n_stamps;
    if (int_field(src, "n_values", &f->n_values) < 0 || int_field(src, "height", &f->height) < 0
        || int_field(src, "thickness", &f->thickness) < 0
        || int_field(src, "frame_size", &frame_size) < 0
        || float_field(src, "min_thickness", &f->min_thickness) < 0
        || float_field(src, "tolerance", &f->tolerance) < 0
        || !(f->thickness_times_height = copy_field(mem, src, "thickness_times_height", 'd',
                                                    -1, &n_cells))
        || !(f->coordinate = copy_field(mem, src, "coordinate", 'q', n_cells, NULL))
        || !(f->stamp_position = copy_field(mem, src, "stamp_position", 'q', -1, &n_stamps)))
        return -1;
    const int64_t nv = f->n_values, n = n_cells * nv;
    f->n_cells = n_cells;
    f->n_stamps = n_stamps;
    self->frame_size = (Py_ssize_t)frame_size;
    if (n_cells < 1 || nv < 1 || f->height < 0 || f->height >= nv || f->thickness < 0
        || f->thickness >= nv) {
        PyErr_SetString(PyExc_ValueError, "FrameMap: inconsistent sizes or indices");
        return -1;
    }
    if (!(f->maps = copy_field(mem, src, "maps", 'd', n * 4, NULL))
        || !(f->position = copy_field(mem, src, "position", 'q', n, NULL)))
        return -1;
    for (int64_t i = 0; i < n; i++)
        if (f->position[i] < 0 || f->position[i] + 8 > frame_size) {
            PyErr_SetString(PyExc_ValueError, "FrameMap: a value lies outside the frame");
            return -1;
        }
    for (int64_t k = 0; k < n_stamps; k++)
        if (f->stamp_position[k] < 0 || f->stamp_position[k] + 8 > frame_size) {
            PyErr_SetString(PyExc_ValueError, "FrameMap: a stamp lies outside the frame");
            return -1;
        }
    f->values = keep(mem, calloc((size_t)(2 * n), sizeof(double)));
    if (!f->values) {
        PyErr_NoMemory();
        return -1;
    }
    f->last = f->values + n;
    return 0;
}

static PyObject *FrameMap_update(FrameMapObject *self, PyObject *const *args, Py_ssize_t n)
{
    if (n != 4) {
        PyErr_SetString(PyExc_TypeError, "update(x, frame, force, stamp_ns)");
        return NULL;
    }
    if (built_ready((PyObject *)self) < 0)
        return NULL;
    int force = PyObject_IsTrue(args[2]);
    long long stamp = PyLong_AsLongLong(args[3]);
    if (force < 0 || (stamp == -1 && PyErr_Occurred()))
        return NULL;
    buf x;
    if (get_buffer(args[0], &x, 'd', -1, 0, "x") < 0)
        return NULL;
    const ds_frame_map *f = &self->f;
    for (int64_t c = 0; c < f->n_cells; c++)
        if (f->coordinate[c] < 0 || f->coordinate[c] >= x.view.len / 8) {
            release(&x);
            PyErr_SetString(PyExc_ValueError, "x: shorter than the model's state");
            return NULL;
        }
    Py_buffer frame;
    if (PyObject_GetBuffer(args[1], &frame, PyBUF_SIMPLE | PyBUF_WRITABLE) < 0) {
        release(&x);
        return NULL;
    }
    int written = 0;
    if (frame.len != self->frame_size)
        PyErr_Format(PyExc_ValueError, "frame: expected %zd bytes, got %zd", self->frame_size,
                     frame.len);
    else
        written = ds_frame_update(&self->f, x.view.buf, frame.buf, force, (int64_t)stamp);
    PyBuffer_Release(&frame);
    release(&x);
    if (PyErr_Occurred())
        return NULL;
    return PyBool_FromLong(written);
}

static PyMethodDef FrameMap_methods[] = {
    {"update", (PyCFunction)(void (*)(void))FrameMap_update, METH_FASTCALL,
     "update(x, frame, force, stamp_ns) -> written: the frame's values at state x; written "
     "into the frame bytes (with the stamp) when force or one moved by more than tolerance"},
    {NULL}
};

static PyTypeObject FrameMapType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "det_sim_ros.core._ckernel.FrameMap",
    .tp_doc = "FrameMap(fields): marker frames of one-coordinate cells, from named fields",
    .tp_basicsize = sizeof(FrameMapObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)FrameMap_init,
    .tp_dealloc = Built_dealloc,
    .tp_methods = FrameMap_methods,
};

/* ---------------------------------------------------------------- SampleCodec */

typedef struct {
    PyObject_HEAD
    arena mem;                          /* first: the BuiltObject prefix */
    ds_sample_wire w;
    unsigned char *messages;            /* the messages' bytes: template, then each sample */
    const int64_t *message_start;       /* n_messages + 1 byte offsets */
    int64_t n_outputs;                  /* the output vector is at least this long */
} SampleCodecObject;

static int SampleCodec_init(SampleCodecObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *src;
    if (built_fields((PyObject *)self, args, kwds, &src) < 0)
        return -1;
    ds_sample_wire *w = &self->w;
    arena *mem = &self->mem;
    Py_ssize_t n, n_starts;
    if (!(w->source = copy_field(mem, src, "source", 'q', -1, &n))
        || !(w->op = copy_field(mem, src, "op", 'q', n, NULL))
        || !(w->a = copy_field(mem, src, "a", 'd', n, NULL))
        || !(w->b = copy_field(mem, src, "b", 'd', n, NULL))
        || !(w->position = copy_field(mem, src, "position", 'q', n, NULL))
        || !(self->message_start = copy_field(mem, src, "message_start", 'q', -1, &n_starts))
        || !(w->stamp_position = copy_field(mem, src, "stamp_position", 'q', n_starts - 1,
                                            NULL)))
        return -1;
    w->n_values = n;
    w->n_messages = n_starts - 1;
    PyObject *template = PyObject_GetAttrString(src, "template");
    if (!template)
        return -1;
    if (!PyBytes_Check(template) || w->n_messages < 1 || self->message_start[0] != 0
        || self->message_start[w->n_messages] != PyBytes_GET_SIZE(template)) {
        Py_DECREF(template);
        PyErr_SetString(PyExc_ValueError,
                        "SampleCodec: template must be the messages' bytes, message_start "
                        "their offsets from 0 to its length");
        return -1;
    }
    const int64_t size = PyBytes_GET_SIZE(template);
    self->messages = keep(mem, malloc((size_t)size));
    if (!self->messages) {
        Py_DECREF(template);
        PyErr_NoMemory();
        return -1;
    }
    memcpy(self->messages, PyBytes_AS_STRING(template), (size_t)size);
    Py_DECREF(template);
    for (int64_t k = 0; k < w->n_messages; k++)
        if (self->message_start[k + 1] < self->message_start[k]
            || w->stamp_position[k] < self->message_start[k]
            || w->stamp_position[k] + 8 > self->message_start[k + 1]) {
            PyErr_SetString(PyExc_ValueError, "SampleCodec: a stamp lies outside its message");
            return -1;
        }
    self->n_outputs = 0;
    for (int64_t i = 0; i < n; i++) {
        if (w->position[i] < 0 || w->position[i] + 8 > size || w->source[i] < 0
            || w->op[i] < DS_WIRE_COPY || w->op[i] > DS_WIRE_SCALED) {
            PyErr_SetString(PyExc_ValueError,
                            "SampleCodec: a value lies outside the messages, or has a bad "
                            "source or op");
            return -1;
        }
        if (w->source[i] + 1 > self->n_outputs)
            self->n_outputs = w->source[i] + 1;
    }
    return 0;
}

static PyObject *SampleCodec_encode(SampleCodecObject *self, PyObject *const *args,
                                    Py_ssize_t n)
{
    if (n != 2) {
        PyErr_SetString(PyExc_TypeError, "encode(out, stamp_ns)");
        return NULL;
    }
    if (built_ready((PyObject *)self) < 0)
        return NULL;
    long long stamp = PyLong_AsLongLong(args[1]);
    if (stamp == -1 && PyErr_Occurred())
        return NULL;
    buf out;
    if (get_buffer(args[0], &out, 'd', -1, 0, "out") < 0)
        return NULL;
    if (out.view.len / 8 < self->n_outputs) {
        release(&out);
        PyErr_Format(PyExc_ValueError, "out: expected at least %lld outputs, got %zd",
                     (long long)self->n_outputs, out.view.len / 8);
        return NULL;
    }
    ds_wire_encode(&self->w, out.view.buf, (int64_t)stamp, self->messages);
    release(&out);
    const int64_t m = self->w.n_messages;
    PyObject *result = PyList_New((Py_ssize_t)m);
    for (int64_t k = 0; result && k < m; k++) {
        const int64_t start = self->message_start[k];
        PyObject *data = PyBytes_FromStringAndSize((const char *)self->messages + start,
                                                   self->message_start[k + 1] - start);
        if (!data) {
            Py_CLEAR(result);
            break;
        }
        PyList_SET_ITEM(result, k, data);
    }
    return result;
}

static PyMethodDef SampleCodec_methods[] = {
    {"encode", (PyCFunction)(void (*)(void))SampleCodec_encode, METH_FASTCALL,
     "encode(out, stamp_ns) -> [bytes]: every output message of the sample at output "
     "vector out (float64), stamped stamp_ns"},
    {NULL}
};

static PyTypeObject SampleCodecType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "det_sim_ros.core._ckernel.SampleCodec",
    .tp_doc = "SampleCodec(fields): one sample's output messages, from named fields",
    .tp_basicsize = sizeof(SampleCodecObject),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)SampleCodec_init,
    .tp_dealloc = Built_dealloc,
    .tp_methods = SampleCodec_methods,
};

/* ---------------------------------------------------------------- pack_records */

/* An int argument in [0, limit]. */
static int bounded_int(PyObject *obj, unsigned long long limit, unsigned long long *out,
                       const char *what)
{
    unsigned long long v = PyLong_AsUnsignedLongLong(obj);
    if (v == (unsigned long long)-1 && PyErr_Occurred()) {
        PyErr_Format(PyExc_ValueError, "%s: expected an int in [0, %llu]", what, limit);
        return -1;
    }
    if (v > limit) {
        PyErr_Format(PyExc_ValueError, "%s: expected an int in [0, %llu]", what, limit);
        return -1;
    }
    *out = v;
    return 0;
}

/*
 * pack_records(channel_ids, first_sequences, times, rows, sizes) -> (records, count):
 * the MCAP Message records of consecutive samples, sample j's message i on channel
 * channel_ids[i] with sequence first_sequences[i] + j at log (and publish) time times[j],
 * payload rows[j][i]. It stops before the first row whose payloads are not ``sizes`` long.
 */
static PyObject *pack_records(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    (void)module;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError,
                        "pack_records(channel_ids, first_sequences, times, rows, sizes)");
        return NULL;
    }
    PyObject *channels = NULL, *firsts = NULL, *times = NULL, *rows = NULL, *sizes = NULL;
    PyObject *result = NULL, *records = NULL;
    enum { MAX_WIDTH = 64 };
    unsigned long long channel[MAX_WIDTH], first[MAX_WIDTH], size[MAX_WIDTH];
    if (!(channels = PySequence_Fast(args[0], "channel_ids: a sequence"))
        || !(firsts = PySequence_Fast(args[1], "first_sequences: a sequence"))
        || !(times = PySequence_Fast(args[2], "times: a sequence"))
        || !(rows = PySequence_Fast(args[3], "rows: a sequence"))
        || !(sizes = PySequence_Fast(args[4], "sizes: a sequence")))
        goto done;
    const Py_ssize_t width = PySequence_Fast_GET_SIZE(channels);
    Py_ssize_t n = PySequence_Fast_GET_SIZE(rows);
    if (width < 1 || width > MAX_WIDTH || PySequence_Fast_GET_SIZE(firsts) != width
        || PySequence_Fast_GET_SIZE(sizes) != width || PySequence_Fast_GET_SIZE(times) < n) {
        PyErr_SetString(PyExc_ValueError, "pack_records: channel_ids, first_sequences and "
                        "sizes must be as long (1..64), times at least as long as rows");
        goto done;
    }
    unsigned long long sample_bytes = 0;
    for (Py_ssize_t i = 0; i < width; i++) {
        if (bounded_int(PySequence_Fast_GET_ITEM(channels, i), 0xffff, &channel[i],
                        "channel_ids") < 0
            || bounded_int(PySequence_Fast_GET_ITEM(firsts, i), 0xffffffffULL, &first[i],
                           "first_sequences") < 0
            || bounded_int(PySequence_Fast_GET_ITEM(sizes, i), 1ULL << 40, &size[i],
                           "sizes") < 0)
            goto done;
        sample_bytes += DS_RECORD_HEAD + size[i];
    }
    Py_ssize_t count = 0;     /* the rows that have ``sizes`` */
    for (; count < n; count++) {
        PyObject *row = PySequence_Fast_GET_ITEM(rows, count);
        if (!(PyList_Check(row) || PyTuple_Check(row)) || PySequence_Fast_GET_SIZE(row) != width)
            break;
        PyObject **items = PySequence_Fast_ITEMS(row);
        Py_ssize_t i = 0;
        while (i < width && PyBytes_Check(items[i])
               && (unsigned long long)PyBytes_GET_SIZE(items[i]) == size[i])
            i++;
        if (i < width)
            break;
    }
    records = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(count * sample_bytes));
    if (!records)
        goto done;
    unsigned char *at = (unsigned char *)PyBytes_AS_STRING(records);
    for (Py_ssize_t j = 0; j < count; j++) {
        unsigned long long t;
        if (bounded_int(PySequence_Fast_GET_ITEM(times, j), 0xffffffffffffffffULL, &t,
                        "times") < 0)
            goto done;
        PyObject **items = PySequence_Fast_ITEMS(PySequence_Fast_GET_ITEM(rows, j));
        for (Py_ssize_t i = 0; i < width; i++) {
            ds_record_head(at, (uint16_t)channel[i], (uint32_t)(first[i] + (unsigned long long)j),
                           t, size[i]);
            memcpy(at + DS_RECORD_HEAD, PyBytes_AS_STRING(items[i]), (size_t)size[i]);
            at += DS_RECORD_HEAD + size[i];
        }
    }
    result = Py_BuildValue("(On)", records, count);
done:
    Py_XDECREF(records);
    Py_XDECREF(channels);
    Py_XDECREF(firsts);
    Py_XDECREF(times);
    Py_XDECREF(rows);
    Py_XDECREF(sizes);
    return result;
}

static PyMethodDef module_functions[] = {
    {"pack_records", (PyCFunction)(void (*)(void))pack_records, METH_FASTCALL,
     "pack_records(channel_ids, first_sequences, times, rows, sizes) -> (records, count): "
     "the MCAP Message records of consecutive samples (see wire.c)"},
    {NULL}
};

/* ---------------------------------------------------------------- module */

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ckernel",
    "Compiled DET-beam kernel: the model's rhs/outputs and the stepping core (see detsim.h).",
    -1, module_functions,
};

PyMODINIT_FUNC PyInit__ckernel(void)
{
    if (PyType_Ready(&ModelType) < 0 || PyType_Ready(&StepperType) < 0
        || PyType_Ready(&FrameMapType) < 0 || PyType_Ready(&SampleCodecType) < 0)
        return NULL;
    PyObject *mod = PyModule_Create(&module);
    if (!mod)
        return NULL;
    Py_INCREF(&ModelType);
    Py_INCREF(&StepperType);
    Py_INCREF(&FrameMapType);
    Py_INCREF(&SampleCodecType);
    if (PyModule_AddObject(mod, "Model", (PyObject *)&ModelType) < 0
        || PyModule_AddObject(mod, "Stepper", (PyObject *)&StepperType) < 0
        || PyModule_AddObject(mod, "FrameMap", (PyObject *)&FrameMapType) < 0
        || PyModule_AddObject(mod, "SampleCodec", (PyObject *)&SampleCodecType) < 0
        || PyModule_AddIntConstant(mod, "OK", DS_OK) < 0
        || PyModule_AddIntConstant(mod, "BAD_STRETCH", DS_BAD_STRETCH) < 0
        || PyModule_AddIntConstant(mod, "NON_FINITE", DS_NON_FINITE) < 0
        || PyModule_AddIntConstant(mod, "BAD_SLOPE", DS_BAD_SLOPE) < 0
        || PyModule_AddIntConstant(mod, "CELL_OUTPUTS", DS_CELL_OUTPUTS) < 0) {
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
