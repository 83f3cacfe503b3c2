# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""Magnetic disturbance detection, the component (fusion/_magdist.pxd; docs/estimators.md,
"Magnetic disturbances"): a filter that uses the magnetometer declares `fusion.params.MAGDIST`
in its PARAMS and holds a MagDetector as `est.magd`; the properties below then read it."""
from operator import attrgetter

from libc.math cimport M_PI

from fusion._core import struct_fields


cdef class MagDetector:
    """The tolerances and state of the disturbance detector a filter holds as `est.magd`:
    time, norm_tol, dip_tol_deg, new_time (the magdist_* parameters), rejected."""

    def __init__(self, p):
        """p: the holder's checked parameters (Estimator._take_params), MAGDIST's among them."""
        self.time, self.norm_tol = p["magdist_time"], p["magdist_norm_tol"]
        self.dip_tol_deg, self.new_time = p["magdist_dip_tol"], p["magdist_new_time"]
        self.dip_tol = self.dip_tol_deg * (M_PI / 180.0)
        magd_clear(self)

    cdef list fields(self):
        return struct_fields(<MagDistState[:1]>&self.s, None, "magd_")

    @property
    def rejected(self):
        """Magnetometer samples rejected as disturbed since the last reset."""
        return self.s.rejected


def _of_magd(attr, doc):
    return property(attrgetter("magd." + attr), doc=doc)


#: The holder's disturbance properties, read from its `magd`: in its class body,
#: ``magdist_time, magdist_norm_tol, magdist_dip_tol, magdist_new_time, mag_rejected = MAGDIST_PROPERTIES``
MAGDIST_PROPERTIES = (
    _of_magd("time", "s of rejection at most, then the current field is the reference; 0: "
             "disturbance detection off (docs/estimators.md, \"Magnetic disturbances\")."),
    _of_magd("norm_tol", "relative: a field whose norm differs from the reference by more is disturbed."),
    _of_magd("dip_tol_deg", "deg: a field whose dip differs from the reference's by more is disturbed."),
    _of_magd("new_time", "s: a new field steady this long while the sensor turns becomes the reference."),
    _of_magd("rejected", "Magnetometer samples rejected as disturbed since the last reset."))
