"""Controllers at the rig's authority limit (issue: controllers that stay safe at the rig's
edges): every built-in, its output pinned at a limit by a torque beyond what the joint can
hold, recovers when the torque goes, with no limit-to-limit swinging and no trip.

Through the real loop on a virtual clock (bench/scenarios.py)."""
import math

import pytest

from bench import scenarios as S

BUILT_IN = ["pid", "smc", "smc_dob", "sac", "lti", "lti_dob"]
MIDDLE = 1  # the weak joint: 0.133 N m per volt, -4..+6 V; pushed for 2 s (at up to 17 deg/s: well inside its limits)


def pin_and_release(name: str, volts_worth: float, pinned_s: float = 2.0, after_s: float = 12.0):
    """Hold the middle joint, push it with a torque worth ``volts_worth`` volts (beyond its
    range) for ``pinned_s``, release; the share of pinned cycles at a limit, the error
    when released, and the error [deg] and output [V] each cycle after."""
    # the tracking rule would rightly trip a joint pushed this far: this test is about what comes after
    loop = S.make_loop(name, options=S.example_options(name), replace=S.NO_TRACKING_RULE)
    loop.hold()
    loop.run(3000)
    reference = loop.reference[0][MIDDLE]
    lo, hi = loop.context.u_min[MIDDLE], loop.context.u_max[MIDDLE]
    arm = loop.io.transport.arm
    arm.disturbance_nm[MIDDLE] = loop.context.models[MIDDLE].kt * volts_worth
    at_limit = 0
    cycles = int(pinned_s / loop.period)
    for _ in range(cycles):
        loop.run(1)
        at_limit += loop.u[MIDDLE] in (lo, hi)
    released_error = math.degrees(reference - loop.angles[MIDDLE])
    arm.disturbance_nm[MIDDLE] = 0.0
    errors, outputs = [], []
    for _ in range(int(after_s / loop.period)):
        loop.run(1)
        errors.append(math.degrees(reference - loop.angles[MIDDLE]))
        outputs.append(loop.u[MIDDLE])
    return loop, at_limit / cycles, released_error, errors, outputs, (lo, hi)


@pytest.mark.slow
@pytest.mark.parametrize("volts_worth", [8.0, -7.5])
@pytest.mark.parametrize("name", BUILT_IN)
def test_an_output_pinned_at_its_limit_recovers_when_the_push_goes(name, volts_worth):
    loop, pinned, released_error, errors, outputs, (lo, hi) = pin_and_release(name, volts_worth)
    assert loop.state.value == "enabled", loop.supervisor.cause
    assert pinned > 0.6, f"the push did not pin the output ({pinned:.0%} of cycles at a limit)"
    assert abs(released_error) > 3.0  # the joint was pushed off: there is something to recover
    # back within 1.5 deg within 10 s (the joint comes back at the rig's authority, a few deg/s)
    back = next((i for i, e in enumerate(errors) if abs(e) < 1.5), None)
    assert back is not None and back * loop.period < 10.0, f"not back: error {errors[-1]:.2f} deg at the end"
    # and stays: a wound-up integrator overshoots by more than the error it started from; the
    # push's own memory (the integral held it off) may overshoot by a part of it
    overshoot = max(abs(e) for e in errors[back:])
    assert overshoot < 0.5 * abs(released_error), f"overshot by {overshoot:.2f} deg after {released_error:.2f}"

    far_limit = hi if released_error < 0 else lo  # a wound-up controller swings past the reference to this one
    assert far_limit not in outputs, f"{name} swung to its {far_limit:+.0f} V limit after the release"
    assert abs(errors[-1]) < 1.0
