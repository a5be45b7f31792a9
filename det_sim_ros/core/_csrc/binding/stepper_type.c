/*
 * Stepper(model, ...): a Model's stepping (stepping/: stepper.c, period.c, batch.c): its
 * method table (det_sim_ros.sim.integrators), the charge-transient settings and the per-period
 * step-count control, one count per independent coupled group.
 */
#include "binding/binding.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    PyObject_HEAD
    ModelObject *model;
    ds_stepper st;
    ds_work out_work;   /* outputs after a period: the stepper's own (run() releases the GIL) */
    double *x_start;    /* period(): x at the period's start, put back if its outputs fail */
    int ready;
} StepperObject;

static void Stepper_dealloc(StepperObject *self)
{
    if (self->ready) {
        ds_stepper_free(&self->st);
        ds_work_free(&self->out_work);
        free(self->x_start);
    }
    Py_XDECREF(self->model);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* ``terms`` (``len`` bytes) are rows (i, j, k, c, w) sorted by stage row i, of s >= 1 stages. */
static int valid_terms(const double *terms, Py_ssize_t len, Py_ssize_t s)
{
    const Py_ssize_t nt = len / 40;
    int valid = s >= 1 && len % 40 == 0;
    for (Py_ssize_t t = 0; valid && t < nt; t++) {
        const double *row = terms + 5 * t;
        valid = row[0] >= 0 && row[0] <= s && row[1] >= 0 && row[1] < s && row[2] >= -1
                && row[2] < 60 && (t == 0 || row[0] >= terms[5 * (t - 1)]);
    }
    return valid;
}

/* The kind's options from ``options`` (a dict, or None: none) into o; ``weights`` holds the
 * buffer of the option of that name. -1 with a ValueError naming the option it cannot take. */
static int kind_options(const ds_kind *kind, PyObject *options, Py_ssize_t n_state,
                        ds_kind_options *o, buf *weights)
{
    if (options == Py_None)
        return 0;
    if (!PyDict_Check(options)) {
        PyErr_SetString(PyExc_TypeError, "Stepper: options must be a dict");
        return -1;
    }
    PyObject *key, *value;
    Py_ssize_t pos = 0;
    while (PyDict_Next(options, &pos, &key, &value)) {
        const char *name = PyUnicode_Check(key) ? PyUnicode_AsUTF8(key) : NULL;
        if (!name || !ds_kind_reads(kind, name)) {
            PyErr_Format(PyExc_ValueError, "Stepper: the kind '%s' takes no option %R (it "
                         "reads: %s)", kind->name, key, *kind->options ? kind->options : "none");
            return -1;
        }
        if (strcmp(name, "weights") == 0) {
            if (get_buffer(value, weights, 'd', n_state, 0, "weights") < 0)
                return -1;
            o->weights = weights->view.buf;
            continue;
        }
        const ds_kind_number *field = ds_kind_numbers;
        while (field->name && strcmp(field->name, name) != 0)
            field++;
        const double v = PyFloat_AsDouble(value);
        if (v == -1.0 && PyErr_Occurred())
            return -1;
        if (!field->name || !(v >= 0.0 && v < INFINITY)) {
            PyErr_Format(PyExc_ValueError, "Stepper: option %s must be %s", name,
                         field->name ? "finite and >= 0" : "a field of ds_kind_options");
            return -1;
        }
        *(double *)((char *)o + field->offset) = v;
    }
    return 0;
}

/* The kind of that name, or NULL with a ValueError naming the kinds there are. */
static const ds_kind *kind_named(const char *name)
{
    const ds_kind *kind = ds_kind_named(name);
    if (!kind) {
        char known[128] = "";
        for (int i = 0; ds_kinds[i]; i++) {
            strncat(known, i ? ", " : "", sizeof known - strlen(known) - 1);
            strncat(known, ds_kinds[i]->name, sizeof known - strlen(known) - 1);
        }
        PyErr_Format(PyExc_ValueError, "Stepper: unknown kind '%s' (known: %s)", name, known);
    }
    return kind;
}

static int Stepper_init(StepperObject *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"model", "c", "terms", "embedded", "error_weights", "dt",
                             "z_tol", "fine", "substeps", "tolerance", "min_substeps",
                             "max_substeps", "exponent", "jump_ref", "kind", "options", NULL};
    PyObject *model, *c, *terms, *embedded, *weights, *options = Py_None;
    const char *kind_name = "stages";
    double dt, z_tol, fine, tol, exponent, jump_ref = 0.0;
    long long n0, n_min, n_max;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O!OOOOdddLdLLd|dsO", kwlist, &ModelType,
                                     &model, &c, &terms, &embedded, &weights, &dt, &z_tol, &fine,
                                     &n0, &tol, &n_min, &n_max, &exponent, &jump_ref,
                                     &kind_name, &options))
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
    const ds_kind *kind = kind_named(kind_name);
    ds_kind_options o = {0};
    buf kind_weights = {0};
    if (!kind || kind_options(kind, options, mo->m.n_state, &o, &kind_weights) < 0) {
        release_buffer(&kind_weights);
        return -1;
    }
    const char *refused = kind->refuse(&mo->m, &o);
    if (refused) {
        PyErr_SetString(PyExc_ValueError, refused);
        release_buffer(&kind_weights);
        return -1;
    }
    PyObject *const tables[] = {c, terms, embedded, weights};
    const spec specs[] = {{'d', -1, 0, "c"}, {'d', -1, 0, "terms"}, {'d', -1, 0, "embedded"},
                          {'d', mo->m.n_state, 0, "error_weights"}};
    buf b[4];
    if (get_buffers(tables, specs, 4, b) < 0) {
        release_buffer(&kind_weights);
        return -1;
    }
    const Py_buffer bc = b[0].view, bt = b[1].view, be = b[2].view, bw = b[3].view;
    const Py_ssize_t s = bc.len / 8;
    int rc = -1;
    const Py_ssize_t nt = bt.len / 40;
    const double *tv = bt.buf;
    if (!valid_terms(tv, bt.len, s)) {
        PyErr_SetString(PyExc_ValueError, "method table: terms must be rows (i, j, k, c, w) "
                                          "sorted by stage row i");
    } else if (ds_method_init(&self->st.method, bc.buf, s, tv, nt, be.buf, be.len / 8) < 0) {
        PyErr_NoMemory();
    } else {
        ds_control ctl = {n0, n_min, n_max, tol, exponent};
        self->st.jump_ref = jump_ref;
        self->st.kind = kind;
        self->st.options = o;
        const int init = ds_stepper_init(&self->st, &mo->m, dt, z_tol, fine, &ctl, bw.buf);
        self->x_start = init < 0 ? NULL : calloc((size_t)mo->m.n_state, sizeof(double));
        if (init < 0 || !self->x_start || ds_work_init(&self->out_work, &mo->m) < 0) {
            ds_stepper_free(&self->st);
            free(self->x_start);
            self->x_start = NULL;
            if (init == -2)
                PyErr_SetString(PyExc_ValueError, "a dense linear part needs every stage node "
                                                  "c_i and 1 among the table's phi arguments");
            else
                PyErr_NoMemory();
        } else {
            Py_INCREF(model);
            self->model = mo;
            self->ready = 1;
            rc = 0;
        }
    }
    release_buffers(b, 4);
    release_buffer(&kind_weights);
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
    if (self->st.kind->whole_periods) {
        PyErr_Format(PyExc_ValueError, "advance() steps a table method; the kind '%s' steps "
                     "whole periods (period(), run())", self->st.kind->name);
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
    ds_group *g = &self->st.group[0];
    int status = DS_OK;
    if (g->m->amp) {   /* the amplifier's laws at the start state, as a period sets them */
        ds_stretches(g->m, b[0].view.buf, &g->w, g->w.Us4);   /* w->y */
        ds_amp_laws(g->m, b[0].view.buf, b[1].view.buf, &g->w);
    }
    if (g->lin)   /* the dense linear part at the start state */
        status = ds_linear_update(&self->st, g, b[0].view.buf, b[1].view.buf);
    if (status == DS_OK)
        status = ds_advance(&self->st, g, b[0].view.buf, b[1].view.buf, h, steps, growth);
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
    memcpy(self->x_start, x, (size_t)m->n_state * sizeof(double));
    int status;
    if (self->st.n_groups > 1) {   /* batches take long enough to let other threads run */
        Py_BEGIN_ALLOW_THREADS
        status = ds_period(&self->st, x, u_old, u);
        Py_END_ALLOW_THREADS
    } else {
        status = ds_period(&self->st, x, u_old, u);
    }
    if (status == DS_OK) {
        status = ds_outputs(m, x, u, b[3].view.buf, &self->out_work);
        if (status != DS_OK)   /* a failed period leaves x at its start, whatever failed */
            memcpy(x, self->x_start, (size_t)m->n_state * sizeof(double));
    }
    release_buffers(b, 4);
    return PyLong_FromLong(status);
}

/*
 * run(x, u_held, u_last, U, X, Y) -> (status, periods completed): many periods in one call.
 * Period k holds U[k]; X[0] receives x, X[k + 1] and Y[k + 1] the state and outputs after
 * period k; u_held is the input held now (already booked), u_last the one the last period ran
 * with. x is left at the last good state (X[periods completed]). The GIL is released for the
 * whole run.
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

/* linear_part(x, u, A) -> status: the dense linear part taken at (x, u) into A (n_q 2 x 2 n_q,
 * a model of one group); the stepper takes it anew at its next period. */
static PyObject *Stepper_linear_part(StepperObject *self, PyObject *const *args, Py_ssize_t n)
{
    NEED_READY(self);
    ds_group *g = &self->st.group[0];
    if (n != 3 || !g->lin || self->st.n_groups != 1) {
        PyErr_SetString(PyExc_TypeError, "linear_part(x, u, A): a linearized stepper of one "
                                         "coupled group");
        return NULL;
    }
    const ds_model *m = &self->model->m;
    const int64_t nd = g->lin->nd;
    const spec specs[] = {{'d', m->n_state, 0, "x"}, U_SPEC(m, "u"), {'d', nd * nd, 1, "A"}};
    buf b[3];
    if (get_buffers(args, specs, 3, b) < 0)
        return NULL;
    ds_linear_reset(g->lin);
    const int status = ds_linear_update(&self->st, g, b[0].view.buf, b[1].view.buf);
    memcpy(b[2].view.buf, g->lin->A, (size_t)(nd * nd) * sizeof(double));
    ds_linear_reset(g->lin);
    release_buffers(b, 3);
    return PyLong_FromLong(status);
}

/* matrix_phis(Z, scale, full, half): phi_k(scale Z) and phi_k(scale Z / 2), k = 0..kmax, of
 * an n x n matrix into (kmax + 1) n x n blocks (matrix_phi.c). */
PyObject *matrix_phis(PyObject *module, PyObject *const *args, Py_ssize_t n)
{
    (void)module;
    if (n != 4) {
        PyErr_SetString(PyExc_TypeError, "matrix_phis(Z, scale, full, half)");
        return NULL;
    }
    const double scale = PyFloat_AsDouble(args[1]);
    if (PyErr_Occurred())
        return NULL;
    PyObject *const arrays[] = {args[0], args[2], args[3]};
    const spec specs[] = {{'d', -1, 0, "Z"}, {'d', -1, 1, "full"}, {'d', -1, 1, "half"}};
    buf b[3];
    if (get_buffers(arrays, specs, 3, b) < 0)
        return NULL;
    const Py_ssize_t nn = b[0].view.len / 8, dim = (Py_ssize_t)llround(sqrt((double)nn));
    const Py_ssize_t blocks = nn > 0 ? b[1].view.len / 8 / nn : 0;
    double *work = NULL;
    if (dim < 1 || dim * dim != nn || blocks < 1 || blocks * nn != b[1].view.len / 8
        || b[2].view.len != b[1].view.len) {
        PyErr_SetString(PyExc_ValueError, "matrix_phis: Z n x n, full and half (kmax+1) n n");
    } else if (!(work = malloc((size_t)ds_matrix_phi_work(dim, blocks - 1) * sizeof(double)))) {
        PyErr_NoMemory();
    } else {
        ds_matrix_phis(b[0].view.buf, scale, dim, blocks - 1, b[1].view.buf, b[2].view.buf,
                       work);
    }
    free(work);
    release_buffers(b, 3);
    if (PyErr_Occurred())
        return NULL;
    Py_RETURN_NONE;
}

/* linear_counts() -> (Jacobians taken, weight sets computed, phi chains built anew) summed
 * over the groups. */
static PyObject *Stepper_linear_counts(StepperObject *self, PyObject *unused)
{
    (void)unused;
    NEED_READY(self);
    long long refreshes = 0, fills = 0, chains = 0;
    for (int64_t gi = 0; gi < self->st.n_groups; gi++) {
        const ds_linear *lin = self->st.group[gi].lin;
        if (lin) {
            refreshes += lin->refreshes;
            fills += lin->fills;
            chains += lin->chain_builds;
        }
    }
    return Py_BuildValue("(LLL)", refreshes, fills, chains);
}

/*
 * plant_nan(site, after, lasting=False): a fault for tests. site 'rhs': the after-th right-hand
 * side the stepper evaluates from now (every group's) returns NaN in its first acceleration; 'jacobian':
 * the after-th Jacobian a BDF stepper takes from now gets a NaN. With ``lasting`` every
 * evaluation after it too. after 0 removes the plant.
 */
static PyObject *Stepper_plant_nan(StepperObject *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"site", "after", "lasting", NULL};
    const char *site;
    long long after;
    int lasting = 0;
    NEED_READY(self);
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "sL|p", kwlist, &site, &after, &lasting))
        return NULL;
    const int rhs = strcmp(site, "rhs") == 0, jac = strcmp(site, "jacobian") == 0;
    if ((!rhs && !jac) || after < 0) {
        PyErr_SetString(PyExc_ValueError, "plant_nan: site 'rhs' or 'jacobian', after >= 0");
        return NULL;
    }
    for (int64_t gi = 0; gi < self->st.n_groups; gi++) {
        ds_group *g = &self->st.group[gi];
        if (rhs) {
            g->w.nan_after = after;
            g->w.nan_lasting = lasting;
        } else if (g->bdf) {
            g->bdf->nan_after = after;
            g->bdf->nan_lasting = lasting;
        }
    }
    Py_RETURN_NONE;
}

static PyObject *Stepper_bdf_counts(StepperObject *self, PyObject *unused)
{
    (void)unused;
    NEED_READY(self);
    double jacobians = 0.0, factorizations = 0.0, rejected = 0.0;
    for (int64_t gi = 0; gi < self->st.n_groups; gi++) {
        const ds_bdf *b = self->st.group[gi].bdf;
        if (b) {
            jacobians += b->jacobians;
            factorizations += b->factorizations;
            rejected += b->rejected;
        }
    }
    return Py_BuildValue("(LLL)", (long long)jacobians, (long long)factorizations,
                         (long long)rejected);
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
    double total = 0.0, best = 0.0, watched = 0.0, repeated = 0.0;
    int64_t n = 0;
    for (int64_t g = 0; g < st->n_groups; g++) {
        total += st->group[g].steps;
        watched += st->group[g].watched;
        repeated += st->group[g].repeated;
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
    case 9: return PyFloat_FromDouble(watched);
    case 10: return PyFloat_FromDouble(repeated);
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
    {"linear_part", (PyCFunction)(void (*)(void))Stepper_linear_part, METH_FASTCALL,
     "linear_part(x, u, A) -> status: the dense linear part at (x, u) into A"},
    {"linear_counts", (PyCFunction)Stepper_linear_counts, METH_NOARGS,
     "linear_counts() -> (Jacobians taken, weight sets computed, phi chains built) of a "
     "linearized stepper"},
    {"bdf_counts", (PyCFunction)Stepper_bdf_counts, METH_NOARGS,
     "bdf_counts() -> (Jacobians taken, LU factorizations, steps rejected) of a BDF stepper"},
    {"plant_nan", (PyCFunction)(void (*)(void))Stepper_plant_nan,
     METH_VARARGS | METH_KEYWORDS,
     "plant_nan(site, after, lasting=False): a NaN in the after-th right-hand side ('rhs') "
     "or BDF Jacobian ('jacobian') from now: a fault for tests"},
    {"reset_control", (PyCFunction)Stepper_reset_control, METH_NOARGS,
     "step counts and error estimates back to their initial values"},
    {"group_substeps", (PyCFunction)Stepper_group_substeps, METH_NOARGS,
     "the step count of each coupled group's next period"},
    {NULL}
};

static PyObject *Stepper_kind(StepperObject *self, void *unused)
{
    (void)unused;
    NEED_READY(self);
    return PyUnicode_FromString(self->st.kind->name);
}

static PyGetSetDef Stepper_getset[] = {
    {"kind", (getter)Stepper_kind, NULL, "how each group steps (one of STEPPER_KINDS)", NULL},
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
    {"limit_watched_periods", (getter)Stepper_get, NULL,
     "amplified periods stepped one step at a time for a current limit within reach",
     (void *)9},
    {"periods_repeated", (getter)Stepper_get, NULL,
     "periods repeated with more steps (their estimate over the tolerance), all groups",
     (void *)10},
    {NULL}
};

PyTypeObject StepperType = DS_TYPE(
    Stepper,
    "Stepper(model, c, terms, embedded, error_weights, dt, z_tol, fine, substeps, "
             "tolerance, min_substeps, max_substeps, exponent[, jump_ref])",
    StepperObject, Stepper_init, Stepper_dealloc, Stepper_methods, Stepper_getset);
