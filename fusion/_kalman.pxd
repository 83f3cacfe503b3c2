# The base of the Kalman filters (ekf family, ukf): their noise parameters, on the parts every
# filter the accelerometer and magnetometer correct holds (fusion/_aided.pxd).
from fusion._aided cimport AidedFilter

# their noise and recovery parameters, one struct: set from the checked parameters at once
# (self.kalman = p), read in Python by the KalmanFilter properties of the same names
cdef struct KalmanNoise:
    double gyro_noise       # rad/s/√Hz
    double bias_noise       # rad/s/√s
    double acc_noise        # m/s²/√Hz
    double mag_noise        # 1/√Hz, relative to the field norm
    double q_init_std       # initial std of each quaternion component
    double bias_init_std    # rad/s
    double motion_rate      # rad/s: rate std over unmeasured time (recovery, docs/robustness.md)

cdef class KalmanFilter(AidedFilter):
    cdef readonly KalmanNoise kalman
