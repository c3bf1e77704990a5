"""Physical constants shared by the simulator, the detectors and the controllers."""

#: m/s^2, standard gravity as every paper in the bibliography uses it (rounded to 9.81).
GRAVITY = 9.81
