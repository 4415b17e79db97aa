/* The cost of eq. (14) in C: formation_bench.mpc.cost.batch_cost, to the bit.
 *
 * Same packed problem (cost.pack_problem), same calling convention
 * (optimizers/compiled.py: cost(x, n, d, data, out)), same sequence of IEEE operations
 * as the numba kernel, with the fused multiply-adds of formation_bench.mpc.fused written
 * as C's fma(). It must be compiled with -ffp-contract=off, so that the compiler fuses
 * nothing else; then both kernels give the same numbers on every machine.
 *
 * Why C: the candidates are taken in tiles whose width is a compile-time constant
 * (cost_of_tile is instantiated for every width the dispatcher uses), so the compiler
 * keeps a tile's state in vector registers and no candidate is left to a scalar
 * remainder loop; numba's loops over a run-time batch size leave the remainder of 30
 * or 10 to scalar code and reload the state from memory at every step.
 * docs/explanation/design.md ("The native cost kernel") has the measurements.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define PACKED_HEADER 10 /* cost.PACKED_HEADER */
#define HEADING_RESET_SUBSTEPS 16 /* model.HEADING_RESET_SUBSTEPS */
#define TILE_MAX 32

/* formation_bench.mpc.model: fdlibm's split of pi/2 and its minimax polynomials */
static const double PIO2_1 = 1.57079632673412561417e00;
static const double PIO2_2 = 6.07710050630396597660e-11;
static const double PIO2_3 = 2.02226624871116645580e-21;
static const double TWO_OVER_PI = 6.36619772367581382433e-01;
static const double S1 = -1.66666666666666324348e-01, S2 = 8.33333333332248946124e-03,
                    S3 = -1.98412698298579493134e-04, S4 = 2.75573137070700676789e-06,
                    S5 = -2.50507602534068634195e-08, S6 = 1.58969099521155010221e-10;
static const double C1 = 4.16666666666666019037e-02, C2 = -1.38888888888741095749e-03,
                    C3 = 2.48015872894767294178e-05, C4 = -2.75573143513906633035e-07,
                    C5 = 2.08757232129817482790e-09, C6 = -1.13596475577881948265e-11;
#define REDUCTION_LIMIT (524288.0 * PIO2_1)

/* fused.fused_cos_sin */
static inline __attribute__((always_inline)) void fused_cos_sin(double angle, double *c,
                                                                double *s) {
    double quadrant = floor(fma(angle, TWO_OVER_PI, 0.5));
    double r = fma(-quadrant, PIO2_3, fma(-quadrant, PIO2_2, fma(-quadrant, PIO2_1, angle)));
    double z = r * r;
    double sin_r = fma(r * z, fma(z, fma(z, fma(z, fma(z, fma(z, S6, S5), S4), S3), S2), S1), r);
    double cos_poly = fma(z, fma(z, fma(z, fma(z, fma(z, C6, C5), C4), C3), C2), C1);
    double cos_r = 1.0 - fma(-z * z, cos_poly, 0.5 * z);
    int64_t n = ((int64_t)quadrant) & 3;
    double sin_a = (n & 1) ? cos_r : sin_r;
    double cos_a = (n & 1) ? sin_r : cos_r;
    *s = (n & 2) ? -sin_a : sin_a;
    *c = ((n + 1) & 2) ? -cos_a : cos_a;
}

/* cost._add_intrusion: penalty[i] += max(0, radius - |(px_i, py_i) - (ox, oy)|)^2 */
static inline __attribute__((always_inline)) void add_intrusion(
    const int W, const double *restrict px, const double *restrict py, double ox, double oy,
    double radius, double *restrict penalty) {
    for (int i = 0; i < W; i++) {
        const double dx = px[i] - ox, dy = py[i] - oy;
        const double gap = radius - sqrt(dx * dx + dy * dy);
        penalty[i] = gap > 0.0 ? penalty[i] + gap * gap : penalty[i];
    }
}

/* cost.batch_cost for candidates first .. first + W - 1 (lanes past n - 1 repeat the last
 * candidate and are not written) */
static inline __attribute__((always_inline)) void cost_of_tile(
    const int W, const double *restrict x, int64_t first, int64_t n, int64_t d,
    const double *restrict data, double *restrict out) {
    const int64_t n_neighbours = (int64_t)data[0], horizon = (int64_t)data[1];
    const int64_t substeps = (int64_t)data[2];
    const double period = data[3], w_dst = data[4], w_centre = data[5];
    const double w_collision = data[6], safety_radius = data[7], w_obstacle = data[9];
    const int64_t n_obstacles = (int64_t)data[8];
    const double *state = data + PACKED_HEADER;
    const double *block_of_step = state + 4;
    const double *distance_targets = block_of_step + horizon;
    const double *centre_target = distance_targets + 2 * n_neighbours * horizon;
    const double *neighbour_positions = centre_target + 2 * horizon;
    const double *obstacles = neighbour_positions + 2 * n_neighbours * horizon;
    const double h = period / (double)substeps;
    const double half_h = 0.5 * h, sixth_h = h / 6.0;
    double px[TILE_MAX], py[TILE_MAX], theta[TILE_MAX], v[TILE_MAX];
    double cos_t[TILE_MAX], sin_t[TILE_MAX], accel[TILE_MAX], omega[TILE_MAX];
    double cos_half[TILE_MAX], sin_half[TILE_MAX], cos_full[TILE_MAX], sin_full[TILE_MAX];
    double total[TILE_MAX], formation[TILE_MAX], penalty[TILE_MAX];
    const double *row[TILE_MAX];
    for (int i = 0; i < W; i++) {
        row[i] = x + (first + i < n ? first + i : n - 1) * d;
        px[i] = state[0];
        py[i] = state[1];
        theta[i] = state[2];
        v[i] = state[3];
        total[i] = 0.0;
    }
    int64_t current_block = -1, substep = 0;
    for (int64_t k = 0; k < horizon; k++) {
        const int64_t block = (int64_t)block_of_step[k];
        if (block != current_block) {
            current_block = block;
            for (int i = 0; i < W; i++) {
                accel[i] = row[i][2 * block];
                omega[i] = row[i][2 * block + 1];
            }
            for (int i = 0; i < W; i++) { /* fused.fused_turn */
                double c, s, half_turn = half_h * omega[i];
                if (fabs(half_turn) < REDUCTION_LIMIT) {
                    fused_cos_sin(half_turn, &c, &s);
                } else {
                    c = cos(half_turn);
                    s = sin(half_turn);
                }
                cos_half[i] = c;
                sin_half[i] = s;
                cos_full[i] = fma(-2.0 * s, s, 1.0);
                sin_full[i] = 2.0 * s * c;
            }
        }
        for (int64_t m = 0; m < substeps; m++) {
            if (substep % HEADING_RESET_SUBSTEPS == 0) {
                for (int i = 0; i < W; i++) fused_cos_sin(theta[i], &cos_t[i], &sin_t[i]);
                for (int i = 0; i < W; i++) {
                    if (!(fabs(theta[i]) < REDUCTION_LIMIT)) {
                        cos_t[i] = cos(theta[i]);
                        sin_t[i] = sin(theta[i]);
                    }
                }
            }
            substep++;
            for (int i = 0; i < W; i++) { /* fused.fused_substep */
                const double ct = cos_t[i], st = sin_t[i], speed = v[i];
                const double v_mid = fma(half_h, accel[i], speed);
                const double v_end = fma(h, accel[i], speed);
                const double cos_mid = fma(ct, cos_half[i], -(st * sin_half[i]));
                const double sin_mid = fma(st, cos_half[i], ct * sin_half[i]);
                const double cos_end = fma(ct, cos_full[i], -(st * sin_full[i]));
                const double sin_end = fma(st, cos_full[i], ct * sin_full[i]);
                const double weight = 4.0 * v_mid;
                const double dx = fma(speed, ct, fma(weight, cos_mid, v_end * cos_end));
                const double dy = fma(speed, st, fma(weight, sin_mid, v_end * sin_end));
                cos_t[i] = cos_end;
                sin_t[i] = sin_end;
                v[i] = v_end;
                px[i] = fma(sixth_h, dx, px[i]);
                py[i] = fma(sixth_h, dy, py[i]);
                theta[i] = fma(h, omega[i], theta[i]);
            }
        }
        /* neighbour outermost, so that the candidates stay innermost here too */
        for (int i = 0; i < W; i++) formation[i] = 0.0;
        for (int64_t j = 0; j < n_neighbours; j++) {
            const double tx = distance_targets[(j * horizon + k) * 2];
            const double ty = distance_targets[(j * horizon + k) * 2 + 1];
            for (int i = 0; i < W; i++) {
                const double dx = px[i] - tx, dy = py[i] - ty;
                formation[i] = fma(dx, dx, fma(dy, dy, formation[i]));
            }
        }
        const double cx_target = centre_target[2 * k], cy_target = centre_target[2 * k + 1];
        for (int i = 0; i < W; i++) {
            const double cx = px[i] - cx_target, cy = py[i] - cy_target;
            total[i] = fma(w_dst, formation[i], fma(w_centre, fma(cx, cx, cy * cy), total[i]));
        }
        if (w_collision > 0.0) {
            for (int i = 0; i < W; i++) penalty[i] = 0.0;
            for (int64_t j = 0; j < n_neighbours; j++) {
                add_intrusion(W, px, py, neighbour_positions[(j * horizon + k) * 2],
                              neighbour_positions[(j * horizon + k) * 2 + 1], safety_radius,
                              penalty);
            }
            for (int i = 0; i < W; i++) total[i] += w_collision * penalty[i];
        }
        if (w_obstacle > 0.0) {
            for (int i = 0; i < W; i++) penalty[i] = 0.0;
            for (int64_t o = 0; o < n_obstacles; o++) {
                add_intrusion(W, px, py, obstacles[3 * o], obstacles[3 * o + 1],
                              obstacles[3 * o + 2], penalty);
            }
            for (int i = 0; i < W; i++) total[i] += w_obstacle * penalty[i];
        }
    }
    for (int i = 0; i < W && first + i < n; i++) out[first + i] = total[i] * period;
}

#define WIDTH(W)                                        \
    case W:                                             \
        cost_of_tile(W, x, first, n, d, data, out);     \
        break;

/* The compiled-objective calling convention (optimizers/compiled.py, COST_SIGNATURE).
 * Tiles of 32; the last tile is the next multiple of 4 (or 1 to 3 candidates as they
 * come), so a batch of 30 runs as one tile of 32 and a batch of 10 as one of 12. */
static void cost(const double *x, int64_t n, int64_t d, const double *data, double *out) {
    for (int64_t first = 0; first < n; first += TILE_MAX) {
        const int64_t left = n - first;
        const int64_t width = left >= TILE_MAX ? TILE_MAX : left < 4 ? left : (left + 3) & ~3;
        switch (width) {
            WIDTH(1) WIDTH(2) WIDTH(3) WIDTH(4) WIDTH(8) WIDTH(12) WIDTH(16)
            WIDTH(20) WIDTH(24) WIDTH(28) WIDTH(32)
        }
    }
}

/* What one core sustains, for the speed benchmark's floor (perf/kernel_speed.py):
 * rounds of 64 independent chains a = a * m + c, fused or as a separate multiply and add,
 * compiled with the kernel's flags; the chains keep every pipeline busy and stay in
 * registers. Returns their sum, so that nothing is left out. */
#define CHAINS 64 /* 8 vectors of 8: enough to fill two FMA pipes of latency 4 */
static PyObject *multiply_add_chains(PyObject *self, PyObject *args) {
    long long rounds;
    int fused;
    if (!PyArg_ParseTuple(args, "Lp", &rounds, &fused)) return NULL;
    double chain[CHAINS];
    for (int i = 0; i < CHAINS; i++) chain[i] = 1.0 + 1e-3 * i;
    const double m = 0.999999, c = 1e-7;
    Py_BEGIN_ALLOW_THREADS
    if (fused) {
        for (long long r = 0; r < rounds; r++)
            for (int i = 0; i < CHAINS; i++) chain[i] = fma(chain[i], m, c);
    } else {
        for (long long r = 0; r < rounds; r++)
            for (int i = 0; i < CHAINS; i++) chain[i] = chain[i] * m + c;
    }
    Py_END_ALLOW_THREADS
    double sum = 0.0;
    for (int i = 0; i < CHAINS; i++) sum += chain[i];
    return PyFloat_FromDouble(sum);
}

/* A float64 C-contiguous buffer of ndim dimensions (writable if asked), or an error naming it. */
static int float64_view(PyObject *object, Py_buffer *view, int ndim, int writable,
                        const char *name) {
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(object, view, flags) < 0) return -1;
    if (view->ndim != ndim || view->itemsize != 8 || view->format == NULL ||
        strcmp(view->format, "d") != 0) {
        PyErr_Format(PyExc_ValueError, "%s must be a C-contiguous float64 array of %d "
                     "dimension(s)", name, ndim);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

/* costs(decisions, packed, out): cost() from Python, on decisions (n, d), the packed problem
 * and out (n,), all C-contiguous float64; what a call from Python costs besides the kernel
 * is then about a numba dispatch's, a third of a ctypes call's. */
static PyObject *costs(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "costs(decisions, packed, out) takes 3 arguments");
        return NULL;
    }
    Py_buffer x, data, out;
    if (float64_view(args[0], &x, 2, 0, "decisions") < 0) return NULL;
    if (float64_view(args[1], &data, 1, 0, "packed") < 0) {
        PyBuffer_Release(&x);
        return NULL;
    }
    if (float64_view(args[2], &out, 1, 1, "out") < 0) {
        PyBuffer_Release(&x);
        PyBuffer_Release(&data);
        return NULL;
    }
    PyObject *result = Py_None;
    if (out.shape[0] != x.shape[0]) {
        PyErr_SetString(PyExc_ValueError, "out must have one entry per row of decisions");
        result = NULL;
    } else if (data.shape[0] < 1) {
        PyErr_SetString(PyExc_ValueError, "packed is empty");
        result = NULL;
    } else {
        cost((const double *)x.buf, x.shape[0], x.shape[1], (const double *)data.buf,
             (double *)out.buf);
    }
    PyBuffer_Release(&x);
    PyBuffer_Release(&data);
    PyBuffer_Release(&out);
    Py_XINCREF(result);
    return result;
}

static PyMethodDef cost_kernel_methods[] = {
    {"costs", (PyCFunction)(void (*)(void))costs, METH_FASTCALL,
     "costs(decisions, packed, out): the costs of decisions (n, d) on the packed problem, "
     "written into out (n,); all C-contiguous float64."},
    {"multiply_add_chains", multiply_add_chains, METH_VARARGS,
     "multiply_add_chains(rounds, fused): rounds of 64 independent multiply-add chains "
     "(fused or not), 2 * 64 * rounds floating-point operations; returns their sum."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef cost_kernel_module = {
    PyModuleDef_HEAD_INIT,
    "_cost_kernel",
    "The cost of eq. (14) in C (formation_bench.mpc.native_cost): its address as "
    "cost_address.",
    -1,
    cost_kernel_methods,
};

PyMODINIT_FUNC PyInit__cost_kernel(void) {
    PyObject *module = PyModule_Create(&cost_kernel_module);
    if (module == NULL) return NULL;
    if (PyModule_AddObject(module, "cost_address", PyLong_FromVoidPtr((void *)&cost)) < 0) {
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
