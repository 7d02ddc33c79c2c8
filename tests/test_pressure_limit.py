"""The rig file's ``[limits] max_pressure_mpa`` bounds V_MV's range (hal/actuation.py): what
``pneumad --check`` and ``describe`` show, what the controllers saturate at and the planner's
feasibility check asks of are the volts whose head pressure the rig delivers."""
import pytest

from controllers.feasibility import Authority
from daemon import main
from daemon.testing.loop import make_loop
from hal import config

# rig-facts §1 [2-29]: p = 0.0899 V + 0.001 MPa; the head chamber biased at 4 V
V_AT_0_7_MPA = (0.7 - 0.001) / 0.0899  # 7.775 V


def limited(tmp_path, mpa: float) -> str:
    text = config.load().source.replace("max_pressure_mpa = 0.9", f"max_pressure_mpa = {mpa}", 1)
    (tmp_path / "rig.toml").write_text(text)
    return text


def test_v_mv_stops_where_the_head_pressure_reaches_the_rigs_limit(tmp_path, capsys):
    text = limited(tmp_path, 0.7)
    top = V_AT_0_7_MPA - 4.0  # 3.775 V above the bias
    assert main.main(["--check", "--config", str(tmp_path / "rig.toml")]) == 0
    assert f"v_mv [V] -4..{top:g}" in capsys.readouterr().out
    loop, _, _ = make_loop(rig_text=text)
    assert [(c.low, c.high) for c in loop.view.command_interfaces] == [(-4.0, pytest.approx(top))] * 2  # describe's
    assert loop.context.u_max == pytest.approx((top, top)) and loop.controller.u_hi == pytest.approx([top, top])
    head, _, _ = loop.actuation.outputs(loop.context.u_max)
    assert head == pytest.approx([0.7e6, 0.7e6])  # the top of the range is the limit, not past it
    authority = Authority.of(loop.rig, loop.context, loop.rig.limits.authority_fraction)
    assert authority.usable(0) == pytest.approx((-3.2, 0.8 * top))  # what a refused set offers


def test_the_built_in_rigs_at_the_regulators_own_limit_keep_their_range():
    for name in ("sim", "sim-3joint"):
        rig = config.load(name)
        assert rig.limits.max_pressure_mpa == 0.9
        loop, _, _ = make_loop(rig_text=rig.source)
        assert set(loop.context.u_min) == {-4.0} and set(loop.context.u_max) == {6.0}  # exactly, as before
