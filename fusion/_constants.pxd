# The physical constants, declared once (C macros, so that the kernels' arithmetic sees the
# literal): cimported by the kernels and envs/_signals.pyx; fusion/_core.pyx exports them to
# Python, where fusion.constants documents them (the one Python name for each).
cdef extern from *:
    """
    #define FUSION_GRAVITY 9.81
    #define FUSION_STANDARD_GRAVITY 9.80665
    #define FUSION_BIAS_MAX 100.0
    """
    # m/s^2: gravity in every model of this project (a still, level accelerometer reads it)
    double GRAVITY "FUSION_GRAVITY"
    # m/s^2 per g: standard gravity, the "g" of datasheets
    double STANDARD_GRAVITY "FUSION_STANDARD_GRAVITY"
    # rad/s: a gyro bias beyond the range of any MEMS gyro (the widest, 70); a learned bias is
    # held within it (a loop its gains made unstable), and a loaded state's
    double BIAS_MAX "FUSION_BIAS_MAX"


cdef extern from "_steps.h":
    # t (s summed from sample steps) has reached duration / gone beyond it, within the steps'
    # rounding (fusion/_steps.h)
    bint lasted "FUSION_LASTED"(double t, double duration) noexcept nogil
    bint outlasted "FUSION_OUTLASTED"(double t, double duration) noexcept nogil
