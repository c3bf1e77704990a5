"""The recovery criteria of the benchmark (docs/concepts.md, "Benchmark metrics"), shared with the training
tasks whose rewards rank behaviour as the benchmark scores it. Plain numbers; `ftcgym.benchmark.metrics`
applies them."""
import math

#: rotor loss: altitude within this of its target (m) ...
ALTITUDE_TOLERANCE = 0.5
#: ... and the thrust axis within this of the policy's reference (rad) ...
THRUST_AXIS_TOLERANCE = math.radians(10.0)
#: ... held this long (s); the airspeed-fault criterion is held as long
RECOVERY_HOLD = 2.0
#: airspeed fault: the airspeed the autopilot uses within this of the true airspeed (m/s) ...
AIRSPEED_TOLERANCE = 2.0
#: ... with roll and pitch inside this flight envelope (rad)
ENVELOPE_ROLL = math.radians(45.0)
ENVELOPE_PITCH = math.radians(30.0)
