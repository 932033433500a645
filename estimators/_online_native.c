/*
 * _online_native.c: one online sample of a pilot filter's C port, read and answered in C.
 *
 * A CPython extension, the module _online_step (built like the C ports,
 * envs/_native.py, with Python's headers added; bound in _online_native.py). Online at 100 Hz the filter's own step costs about a microsecond; entering it
 * through ctypes cost two more, and reading the sample dict and building the plain
 * dicts the observer reports (PilotFilter.update_plain) five more. An OnlineStep does
 * all three in one call, for the members whose port steps one sample as
 *
 *     void <member>_step(const Records *records, const double *inputs_k,
 *                        double u_k, double e_k, int64_t row)
 *
 * (the DEKF's dekf_step, the RML's bank_step, the UKFs' ukf_step), with row 0 of the
 * filter's one-row output. It is what PilotFilter._consume and _plain_of_row do, in
 * the same order and with the same values:
 *
 *   - the sample is read only where sample_floats (estimators/protocol.py) would take
 *     it as it is: a plain dict whose keys are all allowed, every sample key present
 *     with an exact float, finite or NaN (NaN marks a dropped sample), and ``t``, where
 *     given, an exact float. Anything else answers None before the filter is touched,
 *     and the caller takes its Python path, which converts or raises as before;
 *   - the time is ``t`` where given, else t0 + k dt (Python's float(k) * dt, then t0 +);
 *   - the answer is the plain dicts of PilotFilter._plain_of_row, keys in its order,
 *     new each call: mean and std by column, prediction, innovation and its variance
 *     from the row's scalars, and health as EstimateHealth.as_dict gives it. The
 *     health comes from Python (health_of) only when the row's flags or pins change,
 *     and is copied each call with a new ``pinned`` list.
 *
 * The numbers are the port's own: the same function, the same arguments. The object
 * holds the Python objects that own the arrays it points into (``keep``).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

/* The layout version online_abi() reports; its binding checks it. */
#define ONLINE_ABI 1
/* Sample keys a filter reads at most (inputs, e and u); the preview models read four. */
#define MAX_KEYS 16

typedef void (*step_function)(const void *records, const double *inputs_k, double u_k,
                              double e_k, int64_t row);

static PyObject *key_time, *key_mean, *key_std, *key_innovation, *key_innovation_variance,
    *key_prediction, *key_health, *key_pinned;

typedef struct {
    PyObject_HEAD
    step_function step;
    const void *records;
    double *inputs;
    Py_ssize_t n_inputs, n_keys, u_at, e_at, n_p, n_flag;
    const double *mean, *std, *scalar;
    const unsigned char *flag, *pinned;
    double t0, dt;
    PyObject *keys;      /* tuple of str: the sample keys, in the filter's order */
    PyObject *allowed;   /* frozenset of str: the keys a sample may have */
    PyObject *columns;   /* tuple of str: the parameter names, in column order */
    PyObject *health_of; /* callable() -> dict: the health of the row as it is now */
    PyObject *health;    /* the last health dict, or NULL */
    PyObject *keep;      /* owner of the arrays pointed into */
    unsigned char health_key[2 * MAX_KEYS + 64];
} OnlineStep;

static int online_traverse(OnlineStep *self, visitproc visit, void *arg)
{
    Py_VISIT(self->keys);
    Py_VISIT(self->allowed);
    Py_VISIT(self->columns);
    Py_VISIT(self->health_of);
    Py_VISIT(self->health);
    Py_VISIT(self->keep);
    return 0;
}

static int online_clear(OnlineStep *self)
{
    /* pointers into arrays ``keep`` owns: never followed once it is cleared */
    self->step = NULL;
    Py_CLEAR(self->keys);
    Py_CLEAR(self->allowed);
    Py_CLEAR(self->columns);
    Py_CLEAR(self->health_of);
    Py_CLEAR(self->health);
    Py_CLEAR(self->keep);
    return 0;
}

static void online_dealloc(OnlineStep *self)
{
    PyObject_GC_UnTrack(self);
    online_clear(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int online_init(OnlineStep *self, PyObject *args, PyObject *kwargs)
{
    static char *names[] = {"step", "records", "inputs", "n_inputs", "keys", "allowed",
                            "u_at", "e_at", "mean", "std", "scalar", "flag", "pinned",
                            "n_flag", "columns", "health_of", "t0", "dt", "keep", NULL};
    unsigned long long step, records, inputs, mean, std, scalar, flag, pinned;
    Py_ssize_t n_inputs, u_at, e_at, n_flag;
    PyObject *keys, *allowed, *columns, *health_of, *keep;
    double t0, dt;
    if (!PyArg_ParseTupleAndKeywords(args, kwargs, "KKKnO!O!nnKKKKKnO!OddO", names, &step,
                                     &records, &inputs, &n_inputs, &PyTuple_Type, &keys,
                                     &PyFrozenSet_Type, &allowed, &u_at, &e_at, &mean, &std,
                                     &scalar, &flag, &pinned, &n_flag, &PyTuple_Type,
                                     &columns, &health_of, &t0, &dt, &keep))
        return -1;
    Py_ssize_t n_keys = PyTuple_GET_SIZE(keys), n_p = PyTuple_GET_SIZE(columns);
    if (!step || !records || !mean || !std || !scalar || !flag || (n_p && !pinned)
        || (n_inputs && !inputs)) {
        PyErr_SetString(PyExc_ValueError, "OnlineStep needs every address but empty ones");
        return -1;
    }
    if (n_keys > MAX_KEYS || n_inputs < 0 || n_inputs > n_keys || u_at < 0 || u_at >= n_keys
        || e_at < 0 || e_at >= n_keys || n_flag < 4 || n_flag + n_p > (Py_ssize_t)sizeof(self->health_key)) {
        PyErr_Format(PyExc_ValueError,
                     "OnlineStep: %zd keys (at most %d), %zd inputs, u at %zd, e at %zd, "
                     "%zd flags (at least 4) and %zd parameters do not fit",
                     n_keys, MAX_KEYS, n_inputs, u_at, e_at, n_flag, n_p);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n_keys; i++)
        if (!PyUnicode_Check(PyTuple_GET_ITEM(keys, i))) {
            PyErr_SetString(PyExc_TypeError, "OnlineStep: keys must be strings");
            return -1;
        }
    if (!PyCallable_Check(health_of)) {
        PyErr_SetString(PyExc_TypeError, "OnlineStep: health_of must be callable");
        return -1;
    }
    online_clear(self);
    self->step = (step_function)(uintptr_t)step;
    self->records = (const void *)(uintptr_t)records;
    self->inputs = (double *)(uintptr_t)inputs;
    self->n_inputs = n_inputs;
    self->n_keys = n_keys;
    self->u_at = u_at;
    self->e_at = e_at;
    self->n_p = n_p;
    self->n_flag = n_flag;
    self->mean = (const double *)(uintptr_t)mean;
    self->std = (const double *)(uintptr_t)std;
    self->scalar = (const double *)(uintptr_t)scalar;
    self->flag = (const unsigned char *)(uintptr_t)flag;
    self->pinned = (const unsigned char *)(uintptr_t)pinned;
    self->t0 = t0;
    self->dt = dt;
    Py_INCREF(keys);
    self->keys = keys;
    Py_INCREF(allowed);
    self->allowed = allowed;
    Py_INCREF(columns);
    self->columns = columns;
    Py_INCREF(health_of);
    self->health_of = health_of;
    Py_INCREF(keep);
    self->keep = keep;
    return 0;
}

/* Read the sample as sample_floats takes it as it is, and step the filter on it.
 * 1: stepped, *t its time; 0: not read (the Python path takes it); -1: an error set. */
static int read_and_step(OnlineStep *self, PyObject *const *args, Py_ssize_t nargs, double *t)
{
    if (self->step == NULL) {
        PyErr_SetString(PyExc_RuntimeError, "OnlineStep is cleared");
        return -1;
    }
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "OnlineStep takes (sample, k)");
        return -1;
    }
    PyObject *sample = args[0];
    long long k = PyLong_AsLongLong(args[1]);
    if (k == -1 && PyErr_Occurred())
        return -1;
    if (!PyDict_CheckExact(sample))
        return 0;
    Py_ssize_t position = 0;
    PyObject *key, *value;
    while (PyDict_Next(sample, &position, &key, &value)) {
        /* an exact str hashes and compares without running Python code, which could
         * change the dict under PyDict_Next; any other key goes the Python way */
        if (!PyUnicode_CheckExact(key))
            return 0;
        int allowed = PySet_Contains(self->allowed, key);
        if (allowed <= 0)
            return allowed;
    }
    double values[MAX_KEYS];
    for (Py_ssize_t i = 0; i < self->n_keys; i++) {
        value = PyDict_GetItemWithError(sample, PyTuple_GET_ITEM(self->keys, i));
        if (value == NULL)
            return PyErr_Occurred() ? -1 : 0;
        if (!PyFloat_CheckExact(value))
            return 0;
        values[i] = PyFloat_AS_DOUBLE(value);
        if (isinf(values[i]))
            return 0;
    }
    value = PyDict_GetItemWithError(sample, key_time);
    if (value == NULL) {
        if (PyErr_Occurred())
            return -1;
        *t = self->t0 + (double)k * self->dt;
    } else if (PyFloat_CheckExact(value)) {
        *t = PyFloat_AS_DOUBLE(value);
    } else {
        return 0;
    }
    for (Py_ssize_t i = 0; i < self->n_inputs; i++)
        self->inputs[i] = values[i];
    self->step(self->records, self->inputs, values[self->u_at], values[self->e_at], 0);
    return 1;
}

static PyObject *values_by_column(OnlineStep *self, const double *row)
{
    PyObject *values = PyDict_New();
    if (values == NULL)
        return NULL;
    for (Py_ssize_t j = 0; j < self->n_p; j++) {
        PyObject *number = PyFloat_FromDouble(row[j]);
        if (number == NULL || PyDict_SetItem(values, PyTuple_GET_ITEM(self->columns, j), number) < 0) {
            Py_XDECREF(number);
            Py_DECREF(values);
            return NULL;
        }
        Py_DECREF(number);
    }
    return values;
}

/* The health dict of the row: Python's (health_of) where the flags or pins changed. */
static PyObject *health_now(OnlineStep *self)
{
    Py_ssize_t n_flag = self->n_flag, n_p = self->n_p;
    if (self->health == NULL || memcmp(self->health_key, self->flag, n_flag) != 0
        || memcmp(self->health_key + n_flag, self->pinned, n_p) != 0) {
        PyObject *health = PyObject_CallNoArgs(self->health_of);
        if (health == NULL)
            return NULL;
        if (!PyDict_CheckExact(health)) {
            Py_DECREF(health);
            PyErr_SetString(PyExc_TypeError, "OnlineStep: health_of must return a dict");
            return NULL;
        }
        Py_XDECREF(self->health);
        self->health = health;
        memcpy(self->health_key, self->flag, n_flag);
        memcpy(self->health_key + n_flag, self->pinned, n_p);
    }
    PyObject *copy = PyDict_Copy(self->health);
    if (copy == NULL)
        return NULL;
    PyObject *pinned = PyDict_GetItemWithError(self->health, key_pinned);
    if (pinned != NULL && PyList_CheckExact(pinned)) {
        PyObject *fresh = PyList_GetSlice(pinned, 0, PY_SSIZE_T_MAX);
        if (fresh == NULL || PyDict_SetItem(copy, key_pinned, fresh) < 0) {
            Py_XDECREF(fresh);
            Py_DECREF(copy);
            return NULL;
        }
        Py_DECREF(fresh);
    } else if (PyErr_Occurred()) {
        Py_DECREF(copy);
        return NULL;
    }
    return copy;
}

static int set_number(PyObject *dict, PyObject *key, double x)
{
    PyObject *number = PyFloat_FromDouble(x);
    if (number == NULL)
        return -1;
    int status = PyDict_SetItem(dict, key, number);
    Py_DECREF(number);
    return status;
}

static int set_new(PyObject *dict, PyObject *key, PyObject *value)
{
    if (value == NULL)
        return -1;
    int status = PyDict_SetItem(dict, key, value);
    Py_DECREF(value);
    return status;
}

/* PilotFilter._plain_of_row's dicts of the row, at time t */
static PyObject *plain_dicts(OnlineStep *self, double t)
{
    PyObject *plain = PyDict_New();
    if (plain == NULL)
        return NULL;
    const double *scalar = self->scalar; /* prediction, innovation, its variance */
    if (set_number(plain, key_time, t) < 0
        || set_new(plain, key_mean, values_by_column(self, self->mean)) < 0
        || set_new(plain, key_std, values_by_column(self, self->std)) < 0
        || set_number(plain, key_innovation, scalar[1]) < 0
        || set_number(plain, key_innovation_variance, scalar[2]) < 0
        || set_number(plain, key_prediction, scalar[0]) < 0
        || set_new(plain, key_health, health_now(self)) < 0) {
        Py_DECREF(plain);
        return NULL;
    }
    return plain;
}

/* Step on the sample; its dicts (plain) or its time, or None where Python must read it */
static PyObject *answer(OnlineStep *self, PyObject *const *args, Py_ssize_t nargs, int plain)
{
    double t;
    int read = read_and_step(self, args, nargs, &t);
    if (read < 0)
        return NULL;
    if (read == 0)
        Py_RETURN_NONE;
    return plain ? plain_dicts(self, t) : PyFloat_FromDouble(t);
}

/* plain(sample, k): PilotFilter.update_plain's dicts */
static PyObject *online_plain(OnlineStep *self, PyObject *const *args, Py_ssize_t nargs)
{
    return answer(self, args, nargs, 1);
}

/* quiet(sample, k): PilotFilter.update_quiet's time */
static PyObject *online_quiet(OnlineStep *self, PyObject *const *args, Py_ssize_t nargs)
{
    return answer(self, args, nargs, 0);
}

static PyMethodDef online_methods[] = {
    {"plain", (PyCFunction)(void (*)(void))online_plain, METH_FASTCALL,
     "plain(sample, k): step on the sample; its plain dicts, or None (not read)."},
    {"quiet", (PyCFunction)(void (*)(void))online_quiet, METH_FASTCALL,
     "quiet(sample, k): step on the sample; its time, or None (not read)."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject OnlineStepType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "_online_step.OnlineStep",
    .tp_basicsize = sizeof(OnlineStep),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "One online sample of a pilot filter's C port, read and answered in C.",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)online_init,
    .tp_dealloc = (destructor)online_dealloc,
    .tp_traverse = (traverseproc)online_traverse,
    .tp_clear = (inquiry)online_clear,
    .tp_methods = online_methods,
};

static PyObject *online_abi(PyObject *module, PyObject *unused)
{
    return PyLong_FromLong(ONLINE_ABI);
}

static PyMethodDef module_methods[] = {
    {"online_abi", online_abi, METH_NOARGS, "The layout version of OnlineStep's arguments."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef online_module = {
    PyModuleDef_HEAD_INIT, "_online_step",
    "One online sample of a pilot filter's C port, read and answered in C.", -1,
    module_methods,
};

PyMODINIT_FUNC PyInit__online_step(void)
{
    struct {
        PyObject **key;
        const char *text;
    } keys[] = {{&key_time, "t"},
                {&key_mean, "mean"},
                {&key_std, "std"},
                {&key_innovation, "innovation"},
                {&key_innovation_variance, "innovation_variance"},
                {&key_prediction, "prediction"},
                {&key_health, "health"},
                {&key_pinned, "pinned"}};
    for (size_t i = 0; i < sizeof(keys) / sizeof(keys[0]); i++)
        if (*keys[i].key == NULL && (*keys[i].key = PyUnicode_InternFromString(keys[i].text)) == NULL)
            return NULL;
    if (PyType_Ready(&OnlineStepType) < 0)
        return NULL;
    PyObject *module = PyModule_Create(&online_module);
    if (module == NULL)
        return NULL;
    Py_INCREF(&OnlineStepType);
    if (PyModule_AddObject(module, "OnlineStep", (PyObject *)&OnlineStepType) < 0) {
        Py_DECREF(&OnlineStepType);
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
