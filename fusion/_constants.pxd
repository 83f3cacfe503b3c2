# The physical constants, declared once (C macros, so that the kernels' arithmetic sees the
# literal): cimported by the kernels and envs/_signals.pyx; fusion/_core.pyx exports them to
# Python, where fusion.constants documents them (the one Python name for each).
cdef extern from *:
    """
    #define FUSION_GRAVITY 9.81
    #define FUSION_STANDARD_GRAVITY 9.80665
    """
    # m/s^2: gravity in every model of this project (a still, level accelerometer reads it)
    double GRAVITY "FUSION_GRAVITY"
    # m/s^2 per g: standard gravity, the "g" of datasheets
    double STANDARD_GRAVITY "FUSION_STANDARD_GRAVITY"
