"""The MAVLink / PX4 bridge: fly any registered policy on a PX4 vehicle, and let PX4 SITL fly in our world.

This package sits *above* the environment, the controllers, the agents and the evaluation harness
(it imports them; nothing below imports it - ``tests/project/test_layout.py`` checks both directions), so
the simulator and the policies stay free of any autopilot protocol.

* :mod:`.frames` - PX4's NED / FRD frames <-> the project's z-up world and FLU body, and the site
  description that places the turbine (local NED or latitude / longitude / altitude).
* :mod:`.thrust` - the policy's collective thrust in newtons <-> PX4's normalised thrust through
  the airframe's thrust curve (checked against PX4's ``MPC_THR_HOVER``).
* :mod:`.link` - MAVLink over UDP / TCP with pymavlink's generated common dialect (no hand-packed
  bytes), a raw telemetry log (tlog) of every message in and out, PX4's mode numbers.
* :mod:`.vehicle` - one PX4 vehicle: its state, COMMAND_LONG with acknowledgements, the set-point
  stream PX4's offboard mode needs and the way out into hold.
* :mod:`.safety` - geofence (box + clearance to the turbine mesh), speed limit, stale state.
* :mod:`.offboard` - ``wt-inspect fly``: the offboard runner (PX4's offboard rules, SET_ATTITUDE_TARGET
  with body rates + thrust, the hold failsafe) writing the evaluation harness's run file.
* :mod:`.sitl` - ``wt-inspect sitl``: the simulator side of PX4's simulator MAVLink interface
  (HIL_SENSOR / HIL_GPS / HIL_STATE_QUATERNION out, HIL_ACTUATOR_CONTROLS in, lock-step).

Needs the optional dependency pymavlink (``pip install 'wt-inspect[px4]'``).
"""
