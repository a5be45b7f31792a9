/*
 * Model(arrays): the compiled model, built from the named fields of
 * det_sim_ros.physics.model.ModelArrays (attribute by attribute: never positional) into its own
 * copy in C structs (ds_model, ds_cell, ds_det); its methods evaluate the physics (physics.c).
 */
#include "binding/binding.h"

#include <stdlib.h>
#include <string.h>

static void Model_dealloc(ModelObject *self)
{
    ds_work_free(&self->w);
    free_arena(&self->mem);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* The sizes and switches of the state layout, and the offsets in x they give. */
static int read_layout(ds_model *m, PyObject *src)
{
    int64_t creep, rc, power, amp, amp_state;
    if (int_field(src, "n_q", &m->n_q) < 0 || int_field(src, "n_cells", &m->n_cells) < 0
        || int_field(src, "n_state", &m->n_state) < 0 || int_field(src, "r_max", &m->r_max) < 0
        || int_field(src, "creep", &creep) < 0 || int_field(src, "rc_source", &rc) < 0
        || int_field(src, "power_monitor", &power) < 0 || int_field(src, "amplifier", &amp) < 0
        || int_field(src, "amp_state", &amp_state) < 0)
        return -1;
    m->creep = (int)creep;
    m->rc_source = (int)rc;
    m->power = (int)power;
    m->amp = (int)(amp && rc);
    m->amp_state = (int)(amp_state && m->amp);
    const int64_t nq = m->n_q, nc = m->n_cells, R = m->r_max;
    if (nq < 1 || nc < 1 || R < 1) {
        PyErr_SetString(PyExc_ValueError, "a model needs at least one cell and coordinate");
        return -1;
    }
    m->i_eps = 2 * nq;
    m->i_qp = m->i_eps + nc * m->creep;
    m->i_va = m->i_qp + nc * m->rc_source;
    m->i_power = m->i_va + nc * m->amp_state;
    if (m->n_state != m->i_power + 2 * m->power) {
        PyErr_SetString(PyExc_ValueError, "n_state does not match the state layout");
        return -1;
    }
    return 0;
}

/* Where each cell's coordinates and quadrature nodes lie, its group and its kinematics. */
typedef struct {
    int64_t *q, *g;                 /* cell_q, cell_g: offsets (n_cells + 1) */
    int64_t *group, *kinematics;    /* cell_group, kinematics (n_cells) */
} cell_index;

/* The cell index and the model's arrays: quadrature, Ritz blocks, reference point, interface
 * mass, group offsets and structure map. */
static int copy_arrays(ds_model *m, arena *mem, PyObject *src, cell_index *index)
{
    const int64_t nq = m->n_q, nc = m->n_cells, R = m->r_max;
    Py_ssize_t n_nodes, n_mi, n_groups1, n_p;
    if (!(index->q = copy_field(mem, src, "cell_q", 'q', nc + 1, NULL))
        || !(index->g = copy_field(mem, src, "cell_g", 'q', nc + 1, NULL))
        || !(index->group = copy_field(mem, src, "cell_group", 'q', nc, NULL))
        || !(index->kinematics = copy_field(mem, src, "kinematics", 'q', nc, NULL)))
        return -1;
    n_nodes = index->g[nc];
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
    return 0;
}

/* Per-cell constants, by name: the beam's (ds_cell) and the DET's (ds_det). */
static const char *const cell_names[] = {"length", "EI", "c2", "c4", "e4"};
static const char *const det_names[] = {"l0", "VY", "C0", "volume", "E_M", "eta_M", "eta_v",
                                        "Rs", "Rp"};
enum { N_CELL_FIELDS = 5, N_DET_FIELDS = 9 };

/* Cell c's layout from the index (0), or -1 with the error set when it is inconsistent. */
static int set_cell(const ds_model *m, const cell_index *index, int64_t c, ds_cell *cell)
{
    const int64_t *kin = index->kinematics;
    cell->q0 = index->q[c];
    cell->nr = index->q[c + 1] - index->q[c];
    cell->g0 = index->g[c];
    cell->g1 = index->g[c + 1];
    cell->group = index->group[c];
    if (cell->nr < 1 || cell->nr > m->r_max || cell->group < 0 || cell->group >= m->n_groups
        || kin[c] < KIN_PAPER || kin[c] > KIN_EXACT
        || cell->g1 - cell->g0 > DS_MAX_CELL_NODES || cell->g1 < cell->g0) {
        PyErr_Format(PyExc_ValueError, "cell %lld: inconsistent layout", (long long)c);
        return -1;
    }
    cell->mass_col = cell->q0 - m->group_q[cell->group];
    cell->kinematics = (int)kin[c];
    cell->kappa = kin[c] == KIN_CONSISTENT ? 1.0 : 0.0;
    return 0;
}

/* Cell c's beam constants and its DET's, with the DET's derived constants. */
static void set_constants(ds_cell *cell, ds_det *d, double *const *cell_f, double *const *det_f,
                          int64_t c)
{
    cell->length = cell_f[0][c];
    cell->EI = cell_f[1][c];
    cell->c2 = cell_f[2][c];
    cell->c4 = cell_f[3][c];
    cell->e4 = cell_f[4][c];
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

/* Each DET's amplifier (amplifier.c): its output time constant, slew rate and current limit. */
static int read_amplifier(ds_model *m, arena *mem, PyObject *src)
{
    const int64_t nc = m->n_cells;
    double *tau, *slew, *imax;
    if (!(tau = copy_field(mem, src, "amp_tau", 'd', nc, NULL))
        || !(slew = copy_field(mem, src, "amp_slew", 'd', nc, NULL))
        || !(imax = copy_field(mem, src, "amp_imax", 'd', nc, NULL)))
        return -1;
    for (int64_t c = 0; c < nc; c++) {
        m->det[c].amp_tau = tau[c];
        m->det[c].amp_slew = slew[c];
        m->det[c].amp_imax = imax[c];
    }
    return 0;
}

/* The cells and DETs (m->cell, m->det) from the index and the per-cell constants. */
static int build_cells(ds_model *m, arena *mem, PyObject *src, const cell_index *index)
{
    const int64_t nc = m->n_cells;
    double *cell_f[N_CELL_FIELDS], *det_f[N_DET_FIELDS];
    for (int i = 0; i < N_CELL_FIELDS; i++)
        if (!(cell_f[i] = copy_field(mem, src, cell_names[i], 'd', nc, NULL)))
            return -1;
    for (int i = 0; i < N_DET_FIELDS; i++)
        if (!(det_f[i] = copy_field(mem, src, det_names[i], 'd', nc, NULL)))
            return -1;
    if (!(m->cell = keep_owned(mem, calloc((size_t)nc, sizeof(ds_cell))))
        || !(m->det = keep_owned(mem, calloc((size_t)nc, sizeof(ds_det)))))
        return -1;
    m->mass_block = 1;
    for (int64_t g = 0; g < m->n_groups; g++)
        if (m->group_q[g + 1] - m->group_q[g] > m->mass_block)
            m->mass_block = m->group_q[g + 1] - m->group_q[g];
    for (int64_t c = 0; c < nc; c++) {
        if (set_cell(m, index, c, &m->cell[c]) < 0)
            return -1;
        set_constants(&m->cell[c], &m->det[c], cell_f, det_f, c);
    }
    return m->amp ? read_amplifier(m, mem, src) : 0;
}

/* The interface mass couples cells of one group only (groups step independently); each
 * cell's own entry MI[c, c] is also kept with the cell (mi_self). */
static int read_interface_mass(const ds_model *m)
{
    const int64_t nc = m->n_cells;
    for (int64_t e = 0; e < m->n_mi; e++) {
        if (m->mi_row[e] < 0 || m->mi_row[e] >= nc || m->mi_col[e] < 0 || m->mi_col[e] >= nc
            || m->cell[m->mi_row[e]].group != m->cell[m->mi_col[e]].group) {
            PyErr_SetString(PyExc_ValueError, "interface mass couples cells of two groups");
            return -1;
        }
    }
    for (int64_t e = 0; e < m->n_mi; e++)
        if (m->mi_row[e] == m->mi_col[e])
            m->cell[m->mi_row[e]].mi_self += m->mi_val[e];
    return 0;
}

/* What the rhs reads built once from the arrays: the node-contiguous copies of B1 and B2
 * (exact.c) and the inverse mass blocks (one-cell groups' mass solve). */
static int derived_tables(ds_model *m, arena *mem)
{
    const size_t size = (size_t)(m->n_nodes * m->r_max) + 1;
    double *t1, *t2, *inv;
    if (!(t1 = keep_owned(mem, calloc(size, sizeof(double))))
        || !(t2 = keep_owned(mem, calloc(size, sizeof(double))))
        || !(inv = keep_owned(mem, malloc(sizeof(double) * (size_t)(m->n_q * m->r_max)))))
        return -1;
    ds_transpose_nodes(m, m->B1, t1);
    ds_transpose_nodes(m, m->B2, t2);
    if (ds_mass_inverse(m, inv) < 0) {
        PyErr_NoMemory();
        return -1;
    }
    m->B1T = t1;
    m->B2T = t2;
    m->Mb_inv = inv;
    return 0;
}

static int Model_init(ModelObject *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"arrays", NULL};
    PyObject *src;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O", kwlist, &src))
        return -1;
    if (self->mem.n)
        return 0;   /* already built */
    ds_model *m = &self->m;
    memset(m, 0, sizeof(*m));
    cell_index index;
    if (read_layout(m, src) < 0 || copy_arrays(m, &self->mem, src, &index) < 0
        || build_cells(m, &self->mem, src, &index) < 0 || read_interface_mass(m) < 0
        || derived_tables(m, &self->mem) < 0)
        return -1;
    m->one_term = m->n_cells == 1 && m->cell[0].nr == 1 && m->cell[0].kinematics != KIN_EXACT;
    if (ds_work_init(&self->w, m) < 0) {
        PyErr_NoMemory();
        return -1;
    }
    return 0;
}

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
    if (m->amp) {   /* the amplifier's laws at this state (while stepping: at each step's start) */
        ds_stretches(m, b[0].view.buf, &self->w, self->w.Us4);   /* w->y */
        ds_amp_laws(m, b[0].view.buf, b[1].view.buf, &self->w);
    }
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

PyTypeObject ModelType = DS_TYPE(
    Model,
    "Model(arrays): the compiled model, built from ModelArrays' named fields",
    ModelObject, Model_init, Model_dealloc, Model_methods, Model_getset);
