# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The IMU model's streaming step (``fusion.imu.IMU.step``) in C.

``StepKernel`` runs the same arithmetic as the Python ``IMU.step`` (kept in fusion/imu.py
as the reference; tests/test_imu_kernel.py checks the two agree), in the same order and
without fused multiply-adds, so that the numbers are the same to the last bit. The random
numbers are the Python model's: the kernel reads the same noise rows, drawn by the same
generator in the same blocks. ``IMU`` loads the kernel from its own state and writes the
state back before a ``simulate`` call, so the two paths can be mixed as before.
"""
cimport numpy as cnp
import numpy as np
from fusion.checks import finite_vector
from libc.math cimport exp, sin, floor, rint, isfinite

cnp.import_array()

# the same rounding as the Python reference: no a * b + c contracted into one fma
cdef extern from *:
    """
    #if defined(__GNUC__) && !defined(__clang__)
    #pragma GCC optimize ("fp-contract=off")
    #endif
    #if defined(__clang__)
    #pragma clang fp contract(off)
    #endif
    """

cdef double TOL = 1e-9            # fusion.imu._TOL
cdef int BLOCK = 512              # fusion.imu._BLOCK
cdef int NCOLS = 34


cdef double _pairwise(const double* a, Py_ssize_t n) noexcept nogil:
    """numpy's pairwise sum of n contiguous doubles (np.sum along a contiguous axis)."""
    cdef double r[8]
    cdef double res
    cdef Py_ssize_t i, j, n2
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[i]
        return res
    elif n <= 128:
        for j in range(8):
            r[j] = a[j]
        i = 8
        while i < n - (n % 8):
            for j in range(8):
                r[j] += a[i + j]
            i += 8
        res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            res += a[i]
            i += 1
        return res
    n2 = n // 2
    n2 -= n2 % 8
    return _pairwise(a, n2) + _pairwise(a + n2, n - n2)


cdef int _read3(object v, double* out, str name, str msg) except -1:
    """3 finite real numbers as the reference's ``checks.finite_vector`` takes them (a tuple of 3 Python
    floats and a float64 array of 3 read directly), else ValueError(msg): a NaN on a step
    without a sample would enter the low-pass and fail a later sample."""
    cdef cnp.ndarray arr
    cdef bint read = False
    if (type(v) is tuple and len(<tuple>v) == 3 and type((<tuple>v)[0]) is float
            and type((<tuple>v)[1]) is float and type((<tuple>v)[2]) is float):
        out[0] = (<tuple>v)[0]
        out[1] = (<tuple>v)[1]
        out[2] = (<tuple>v)[2]
        read = True
    elif type(v) is np.ndarray:
        arr = <cnp.ndarray>v
        if (cnp.PyArray_TYPE(arr) == cnp.NPY_DOUBLE and cnp.PyArray_NDIM(arr) == 1
                and cnp.PyArray_DIM(arr, 0) == 3 and cnp.PyArray_ISBEHAVED_RO(arr)):
            out[0] = (<double*>cnp.PyArray_GETPTR1(arr, 0))[0]
            out[1] = (<double*>cnp.PyArray_GETPTR1(arr, 1))[0]
            out[2] = (<double*>cnp.PyArray_GETPTR1(arr, 2))[0]
            read = True
    if not read:
        x = finite_vector(name, v, 3, msg)         # (the reference's own check)
        out[0] = x[0]
        out[1] = x[1]
        out[2] = x[2]
    elif not (isfinite(out[0]) and isfinite(out[1]) and isfinite(out[2])):
        raise ValueError(f"{msg}, got {v!r}")
    return 0


cdef double _optional(object v, bint* given, double absent=0.0) except? -1.0:
    """A Python number or None as C: v, or absent for None; given (if not NULL) says which."""
    if given != NULL:
        given[0] = v is not None
    return absent if v is None else v


cdef class StepKernel:
    """One IMU's streaming state and constants; see the module docstring."""

    def __cinit__(self):
        self.live = False

    # -- state in and out of the Python model --------------------------------------------
    def load(self, imu):
        """Take constants and state from the Python ``IMU`` (after reset or simulate)."""
        self._load_constants(imu)
        self._load_state(imu)
        self.live = True

    def _load_constants(self, imu):
        """The IMU's specification and its derived constants (fixed between resets)."""
        cdef int i, j
        spec = imu._spec
        self.fs = imu._fs
        self.jitter_s = spec.jitter_s
        self.lim = 0.45 / self.fs
        self.hold = imu._hold
        self.prate = _optional(imu._physics_rate, &self.has_prate)
        self.lpf_g = _optional(spec.gyro.lpf_hz, NULL, -1.0)
        self.lpf_acc = _optional(spec.acc.lpf_hz, NULL, -1.0)
        for i in range(30):
            self.R[i] = imu._R[i]
            self.C[i] = imu._C[i]
        for i in range(2):
            self.ident[i] = imu._ident[i]
            for j in range(9):
                self.M[i][j] = imu._Ml[i][j // 3][j % 3]
        for i in range(6):
            self.b0[i] = imu._b0l[i]
            q = imu._quant6[i]
            self.qlsb[i] = q[0]
            self.qlo[i] = q[1]
            self.qhi[i] = q[2]
            self.qact[i] = q[3]
        self.has_magspec = spec.mag is not None
        self.mag_scale = imu._mag_scale
        if self.has_magspec:
            ms = spec.mag
            self.mag_ident = imu._mag_ident
            for j in range(9):
                self.magS[j] = imu._mag_Sl[j // 3][j % 3]
            for j in range(3):
                self.magh[j] = imu._mag_hl[j]
            self.mnoise = ms.noise_rms
            self.mlsb = imu._mlsb
            self.mlo = imu._mlo
            self.mhi = imu._mhi
            self.mclip = imu._mclip
            self.mrate = _optional(imu._mrate, &self.has_mrate)
        self.vib = imu._vib is not None
        if self.vib:
            self.vib_w = np.ascontiguousarray(imu._vib_w, dtype=np.float64)
            self.vib_phi = np.ascontiguousarray(imu._vib_phi, dtype=np.float64)
            self.vib_buf = np.empty_like(self.vib_w)
            for i in range(6):
                self.vib_amp[i] = imu._vib_amp[i]

    def _load_state(self, imu):
        """What changes from sample to sample: noise buffer, timing, filters, held magnetometer."""
        cdef int i
        for i in range(30):
            self.S[i] = imu._S[i]
        self.gen = imu._gen
        self.buf = np.ascontiguousarray(imu._buf, dtype=np.float64).reshape(-1, NCOLS)
        self.pos = imu._pos
        self.k = imu._k
        self.T_next = imu._T_next
        self.T_prev = _optional(imu._T_prev, &self.has_T_prev)
        self.origin = _optional(imu._origin, &self.has_origin)
        self.steps = imu._steps
        self.tau_last = _optional(imu._tau_last, NULL)
        for i in range(9):
            self.y_last[i] = imu._y_last[i]
            self.y_prev[i] = imu._y_prev[i]
            self.x[i] = imu._x[i]
            self.sum_[i] = imu._sum[i]
            self.lpf_a[i] = imu._lpf_a[i]
            self.lpf_b[i] = imu._lpf_b[i]
        self.cnt = imu._cnt
        self.has_mag_held = imu._mag_held is not None
        if self.has_mag_held:
            for i in range(3):
                self.mag_held[i] = imu._mag_held[i]
        self.mag_on = -1 if imu._mag_on is None else (1 if imu._mag_on else 0)
        self.lpf_dt = _optional(imu._lpf_dt, &self.has_lpf_dt)
        self.slot_last = _optional(imu._mag_slot_last, &self.has_slot)

    def store(self, imu):
        """Write the state back into the Python ``IMU`` (before a ``simulate``)."""
        imu._S = [self.S[i] for i in range(30)]
        imu._buf = np.asarray(self.buf)
        imu._pos = self.pos
        imu._k = self.k
        imu._T_next = self.T_next
        imu._T_prev = self.T_prev if self.has_T_prev else None
        imu._origin = self.origin if self.has_origin else None
        imu._steps = self.steps
        imu._tau_last = self.tau_last if self.steps else None
        imu._y_last = np.array([self.y_last[i] for i in range(9)])
        imu._y_prev = np.array([self.y_prev[i] for i in range(9)])
        imu._x = np.array([self.x[i] for i in range(9)])
        imu._sum = np.array([self.sum_[i] for i in range(9)])
        imu._cnt = self.cnt
        imu._mag_held = np.array([self.mag_held[i] for i in range(3)]) if self.has_mag_held else None
        imu._mag_on = None if self.mag_on < 0 else bool(self.mag_on)
        imu._lpf_dt = self.lpf_dt if self.has_lpf_dt else None
        imu._lpf_a = np.array([self.lpf_a[i] for i in range(9)])
        imu._lpf_b = np.array([self.lpf_b[i] for i in range(9)])
        imu._mag_slot_last = self.slot_last if self.has_slot else None
        self.live = False

    # -- the step ----------------------------------------------------------------------
    cdef int _refill(self) except -1:
        self.buf = self.gen.standard_normal((BLOCK, NCOLS))
        self.pos = 0
        return 0

    cdef void _vibrate(self, double tau) noexcept:
        cdef Py_ssize_t n = self.vib_w.shape[1]
        cdef Py_ssize_t i, j
        cdef double* b
        for i in range(6):
            b = &self.vib_buf[i, 0]
            for j in range(n):
                b[j] = sin(self.vib_w[i, j] * tau + self.vib_phi[i, j])
            self.x[i] = self.x[i] + _pairwise(b, n) * self.vib_amp[i]

    cdef int step_c(self, const double* g, const double* a, const double* m, double dt, bint has_dt) except -1:
        """One physics step (m NULL: no field input). Returns 1 when a sample is due (it is in
        out_g, out_a, out_m, out_t, out_dt, out_index), else 0; dt < 0 or not has_dt: the
        default step."""
        cdef int i, r, c, k0
        cdef bint has_mag = m != NULL
        cdef bint first, fresh
        cdef double tau, tau_prev, T, w, y, v0, v1, v2, slot, lsb, aa
        cdef double vals[9]
        cdef double o[3]
        cdef double* y_
        cdef const double* row
        cdef Py_ssize_t step_index
        for i in range(3):
            self.x[i] = g[i]
            self.x[3 + i] = a[i]
        if has_mag:
            for i in range(3):
                self.x[6 + i] = m[i]
        if self.mag_on < 0:
            self.mag_on = has_mag
        elif self.mag_on != has_mag:
            raise ValueError("mag_true must be given in every step of a record or in none")
        if self.steps == 0:
            if not self.has_origin:
                self.has_origin = True
                self.origin = 0.0
            tau = 0.0
            if self.vib:
                self._vibrate(tau)
            for i in range(9):
                self.y_last[i] = self.x[i]
            first = True
        else:
            if not has_dt:
                if not self.has_prate:
                    raise ValueError("dt must be given (s) when the IMU has no physics_rate_hz")
                dt = 1.0 / self.prate
            elif not (dt > 0) or dt > (1.0 + 1e-6) / self.fs:
                raise ValueError(f"dt must be > 0 and <= the IMU period 1/{self.fs:g} s, got {dt!r}")
            tau = self.tau_last + dt
            if self.vib:
                self._vibrate(tau)
            if not self.has_lpf_dt or dt != self.lpf_dt:
                for i in range(9):
                    self.lpf_a[i] = 0.0
                if self.lpf_g >= 0:
                    aa = exp(-2.0 * 3.141592653589793 * self.lpf_g * dt)
                    self.lpf_a[0] = aa; self.lpf_a[1] = aa; self.lpf_a[2] = aa
                if self.lpf_acc >= 0:
                    aa = exp(-2.0 * 3.141592653589793 * self.lpf_acc * dt)
                    self.lpf_a[3] = aa; self.lpf_a[4] = aa; self.lpf_a[5] = aa
                for i in range(9):
                    self.lpf_b[i] = 1.0 - self.lpf_a[i]
                self.lpf_dt = dt
                self.has_lpf_dt = True
            for i in range(9):
                self.y_prev[i] = self.y_last[i]
                self.y_last[i] = self.y_prev[i] * self.lpf_a[i] + self.x[i] * self.lpf_b[i]
            first = False
        y_ = self.y_last
        tau_prev = self.tau_last
        self.tau_last = tau
        step_index = self.steps
        self.steps += 1
        if not self.hold:
            for i in range(9):
                self.sum_[i] += y_[i]
            self.cnt += 1
        T = self.T_next
        if tau < T - TOL:
            return 0

        # a sample is due
        if self.hold:
            if first or T >= tau - TOL or tau == tau_prev:
                for i in range(9):
                    vals[i] = y_[i]
            else:
                w = (T - tau_prev) / (tau - tau_prev)
                w = 0.0 if w < 0.0 else (1.0 if w > 1.0 else w)
                for i in range(9):
                    vals[i] = (1.0 - w) * self.y_prev[i] + w * y_[i]
        else:
            for i in range(9):
                vals[i] = self.sum_[i] / <double>self.cnt
                self.sum_[i] = 0.0
            self.cnt = 0
        if self.pos >= self.buf.shape[0]:
            self._refill()
        row = &self.buf[self.pos, 0]
        # gyro and accelerometer (IMU._output_one)
        for i in range(30):
            self.S[i] = self.R[i] * self.S[i] + row[1 + i] * self.C[i]
        for i in range(2):
            k0 = 3 * i
            v0 = vals[k0]; v1 = vals[k0 + 1]; v2 = vals[k0 + 2]
            if self.ident[i]:
                o[0] = v0; o[1] = v1; o[2] = v2
            else:
                for r in range(3):
                    o[r] = self.M[i][3 * r] * v0 + self.M[i][3 * r + 1] * v1 + self.M[i][3 * r + 2] * v2
            for r in range(3):
                c = k0 + r
                y = o[r] + ((self.b0[c] + self.S[c] + self.S[6 + c] + self.S[12 + c]) + self.S[18 + c]) + self.S[24 + c]
                lsb = self.qlsb[c]
                if lsb > 0:
                    y = y / lsb
                    if not isfinite(y):     # where the reference's round() raises
                        raise ValueError("gyr_true, acc_true and mag_true must be finite")
                    y = rint(y)
                    y = (self.qlo[c] if y < self.qlo[c] else (self.qhi[c] if y > self.qhi[c] else y)) * lsb
                elif self.qact[c]:
                    y = self.qlo[c] if y < self.qlo[c] else (self.qhi[c] if y > self.qhi[c] else y)
                if i == 0:
                    self.out_g[r] = y
                else:
                    self.out_a[r] = y
        self.out_has_mag = False
        if self.mag_on == 1 and self.has_magspec:
            if self.has_mrate:
                slot = floor(T * self.mrate + TOL)
                fresh = (not self.has_slot) or slot != self.slot_last
                self.slot_last = slot
                self.has_slot = True
            else:
                fresh = True
            if fresh or not self.has_mag_held:
                v0 = vals[6] * self.mag_scale; v1 = vals[7] * self.mag_scale; v2 = vals[8] * self.mag_scale
                if self.mag_ident:
                    o[0] = v0; o[1] = v1; o[2] = v2
                else:
                    for r in range(3):
                        o[r] = self.magS[3 * r] * v0 + self.magS[3 * r + 1] * v1 + self.magS[3 * r + 2] * v2
                for r in range(3):
                    y = o[r] + self.magh[r] + row[31 + r] * self.mnoise
                    if self.mlsb > 0:
                        y = y / self.mlsb
                        if not isfinite(y):
                            raise ValueError("gyr_true, acc_true and mag_true must be finite")
                        y = rint(y)
                        y = (self.mlo if y < self.mlo else (self.mhi if y > self.mhi else y)) * self.mlsb
                    elif self.mclip:
                        y = self.mlo if y < self.mlo else (self.mhi if y > self.mhi else y)
                    self.mag_held[r] = y
                self.has_mag_held = True
            for r in range(3):
                self.out_m[r] = self.mag_held[r] / self.mag_scale
            self.out_has_mag = True
        self.pos += 1
        self.out_dt = T - self.T_prev if self.has_T_prev else 1.0 / self.fs
        self.T_prev = T
        self.has_T_prev = True
        self.k += 1
        w = self.jitter_s * row[0]
        w = -self.lim if w < -self.lim else (self.lim if w > self.lim else w)
        self.T_next = <double>self.k / self.fs + w
        self.out_t = T + self.origin
        self.out_index = step_index
        return 1

    def step(self, gyr_true, acc_true, mag_true, dt, sample_type):
        """``IMU.step`` on the kernel: returns ``sample_type(t, gyr, acc, mag, dt, index)`` or None."""
        cdef double g[3]
        cdef double a[3]
        cdef double m[3]
        cdef double d = 0.0
        _read3(gyr_true, g, "gyr_true", "gyr_true must be 3 finite real numbers (rad/s)")
        _read3(acc_true, a, "acc_true", "acc_true must be 3 finite real numbers (m/s^2)")
        if mag_true is not None:
            _read3(mag_true, m, "mag_true", "mag_true must be 3 finite real numbers or None")
        if dt is not None:
            d = dt
        if not self.step_c(g, a, m if mag_true is not None else NULL, d, dt is not None):
            return None
        return self.sample(sample_type)

    cdef object sample(self, sample_type):
        cdef cnp.npy_intp three = 3
        gy = cnp.PyArray_SimpleNew(1, &three, cnp.NPY_DOUBLE)
        ac = cnp.PyArray_SimpleNew(1, &three, cnp.NPY_DOUBLE)
        cdef double* pg = <double*>cnp.PyArray_DATA(gy)
        cdef double* pa = <double*>cnp.PyArray_DATA(ac)
        cdef double* pm
        cdef int i
        for i in range(3):
            pg[i] = self.out_g[i]
            pa[i] = self.out_a[i]
        mg = None
        if self.out_has_mag:
            mg = cnp.PyArray_SimpleNew(1, &three, cnp.NPY_DOUBLE)
            pm = <double*>cnp.PyArray_DATA(mg)
            for i in range(3):
                pm[i] = self.out_m[i]
        return sample_type(self.out_t, gy, ac, mg, self.out_dt, self.out_index)
