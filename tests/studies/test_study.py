"""Study files: schema, errors that name the loop and field, dependency order, and the
quadrotor study end to end through the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tuner.cli import main
from tuner.studies.schema import InvalidStudyError, load_study, loop_key, parse_study

ROOT = Path(__file__).resolve().parents[2]
QUAD = ROOT / "studies" / "quadrotor.toml"
PROCESS = ROOT / "studies" / "process.toml"


def _study(**loops_over):
    loops = [
        {"name": "pitch", "plant": "1/(s^2+s+1)", "dt": 0.04, "structure": "pid_z"},
        {"name": "x", "inner": "pitch", "plant": "9.81/s^2", "dt": 0.04, "structure": "lead"},
    ]
    for i, upd in loops_over.items():
        loops[int(i[1:])].update(upd)
    return {"name": "t", "loop": loops}


def test_committed_studies_load():
    q = load_study(QUAD)
    assert [lp.name for lp in q.loop] == ["roll", "pitch", "yaw", "x", "y", "altitude", "roll_limited", "pitch_limited",
                                       "yaw_limited"]
    assert {lp.name: lp.inner for lp in q.loop if lp.inner} == {"x": "pitch", "y": "roll"}
    alt = q.get("altitude")
    assert (alt.plant, alt.plant_dt, alt.structure, alt.thesis_controller) == ("0.04/(z-1)", 0.04, "pi", "5+2/(z-1)")
    p = load_study(PROCESS)
    assert len(p.loop) == 5
    for lp in p.loop:  # delays are whole samples
        assert abs(lp.delay / lp.dt - round(lp.delay / lp.dt)) < 1e-9


def test_order_puts_inner_loops_first():
    s = parse_study({"name": "t", "loop": [
        {"name": "x", "inner": "pitch", "plant": "9.81/s^2", "dt": 0.04, "structure": "lead"},
        {"name": "alt", "plant": "1/s", "dt": 0.04, "structure": "pi"},
        {"name": "pitch", "plant": "1/(s^2+s+1)", "dt": 0.04, "structure": "pid_z"},
    ]})
    assert [lp.name for lp in s.order()] == ["pitch", "x", "alt"]
    assert [lp.name for lp in s.chain("x")] == ["pitch", "x"]


@pytest.mark.parametrize("change, message", [
    ({"l0": {"plant": None}}, "loop 'pitch': give exactly one of plant"),
    ({"l0": {"plants": ["1/s"]}}, "loop 'pitch': give exactly one of plant"),
    ({"l1": {"structure": "pidd"}}, "unknown structure 'pidd'"),
    ({"l1": {"inner": "roll"}}, "loop 'x': inner: no loop named 'roll'"),
    ({"l1": {"dt": 0.02}}, "loop 'x': dt: a cascade runs at its inner loop's dt"),
    ({"l0": {"spec": {"phase_margin_min_deg": 120}}}, "loop 'pitch': spec.phase_margin_min_deg: Input should be less"),
    ({"l0": {"spec": {"pm": 60}}}, "loop 'pitch': spec.pm: Extra inputs are not permitted"),
    ({"l0": {"inner": "x"}}, "cascade cycle"),
    ({"l1": {"name": "pitch"}}, "loop names must be unique"),
    ({"l1": {"tyop": 1}}, "loop 'x': tyop: Extra inputs are not permitted"),
])
def test_errors_name_loop_and_field(change, message):
    raw = _study(**change)
    raw["loop"] = [{k: v for k, v in lp.items() if v is not None} for lp in raw["loop"]]
    with pytest.raises(InvalidStudyError, match=message.replace("(", r"\(").replace(".", r"\.")):
        parse_study(raw)


def test_plant_errors_name_the_loop(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text('name = "t"\n[[loop]]\nname = "alt"\nplant = "0.04/(z-1)"\ndt = 0.04\nstructure = "pi"\n')
    with pytest.raises(InvalidStudyError, match=r"loop 'alt': plant: plant is in z: give its sample time dt"):
        load_study(f)
    f.write_text('name = "t"\n[[loop]]\nname = "a"\nplant = "0.1/(z-0.9)"\nplant_dt = 0.2\ndelay = 0.3\ndt = 0.2\n'
                 'structure = "pi"\n')
    with pytest.raises(InvalidStudyError, match=r"loop 'a': delay: 0.3 s is not a whole number of samples of the "
                                                 r"plant's dt=0.2 s"):
        load_study(f)


def test_cli_bad_study_exits_2_with_one_line(tmp_path, capsys):
    f = tmp_path / "bad.toml"
    f.write_text('name = "t"\n[[loop]]\nname = "roll"\nplant = "1/(s+1)"\ndt = 0.04\nstructure = "pid_z"\n'
                 '[loop.spec]\novershoot_max_pct = -1\n')
    assert main(["study", "run", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "loop 'roll': spec.overshoot_max_pct" in err[0]
    f.write_text("name = \n")
    assert main(["study", "run", str(f)]) == 2
    assert "not valid TOML" in capsys.readouterr().err


def test_loop_key_follows_the_inner_loop():
    a = parse_study(_study())
    b = parse_study(_study(l0={"plant": "2/(s^2+s+1)"}))
    c = parse_study(_study(l1={"note": "a comment does not change the result"}))
    assert loop_key(a, "x") != loop_key(b, "x")  # the outer loop's plant depends on the inner loop
    assert loop_key(a, "x") == loop_key(c, "x")


def _metric(v):
    return {"Infinity": math.inf, "NaN": math.nan}.get(v, v) if isinstance(v, str) else v


@pytest.mark.slow
def test_quadrotor_study_end_to_end(tmp_path, capsys):
    """``tuner study run studies/quadrotor.toml``: every loop meets its spec as judged by the
    verifier; report and plots exist and are non-empty; a second run reuses the stored results."""
    out = tmp_path / "q"
    assert main(["study", "run", str(QUAD), "--out", str(out), "--check"]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert set(doc["loops"]) == {"roll", "pitch", "yaw", "x", "y", "altitude", "roll_limited", "pitch_limited",
                                 "yaw_limited"}
    assert doc["meets_spec"] is True
    for name, r in doc["loops"].items():
        assert r["meets_spec"] is True, (name, r.get("failing"), r.get("error"))
        assert not r["failing"]
        assert r["metrics"]["phase_margin_deg"] >= 60 and r["metrics"]["overshoot_pct"] <= 10
        assert math.isfinite(_metric(r["metrics"]["settling_time_s"]))
    for name in ("x", "y"):  # cascades: bandwidths and their ratio, and the position between samples
        c = doc["loops"][name]["cascade"]
        assert c["bandwidth_ratio"] == pytest.approx(c["inner_bandwidth_rad_s"] / c["outer_bandwidth_rad_s"])
        assert c["between_samples"]["ok"] is True
    # the printed controllers, as printed (figures of shared/reference/quadrotor.md)
    th = doc["thesis_as_printed"]
    assert th["roll"]["metrics"]["phase_margin_deg"] == pytest.approx(75.4, abs=0.1)
    assert th["roll"]["metrics"]["settling_time_s"] == pytest.approx(0.43, abs=0.01)
    assert th["altitude"]["metrics"]["overshoot_pct"] == pytest.approx(59, abs=0.5)
    assert th["x"]["metrics"]["stable"] is False and th["y"]["metrics"]["stable"] is False

    report = (out / "report.md").read_text()
    assert "Thesis as printed beside tuned" in report and "## Cascades" in report
    for name in ("roll", "pitch", "yaw", "x", "y", "altitude"):
        assert f"| {name} |" in report
        for kind in ("step", "bode", "nyquist"):
            png = out / "plots" / f"{name}_{kind}.png"
            assert png.stat().st_size > 5000 and png.read_bytes()[:4] == b"\x89PNG"
            assert f"(plots/{name}_{kind}.png)" in report

    # the gains written verify with `tuner verify`
    capsys.readouterr()
    assert main(["verify", str(QUAD), "--gains", str(out / "gains.json")]) == 0

    # re-running the finished study reuses its results at once: nothing is tuned again
    from tuner.studies.runner import Coordinator, default_storage_url, open_storage

    assert main(["study", "run", str(QUAD), "--out", str(out), "--no-plots"]) == 0
    again = json.loads((out / "results.json").read_text())
    assert {n: r["gains"] for n, r in again["loops"].items()} == {n: r["gains"] for n, r in doc["loops"].items()}
    coord = Coordinator(load_study(QUAD), open_storage(default_storage_url(str(out))), observe_only=True)
    for lp in coord.study.loop:
        claims = coord.claim_studies(lp)
        assert len(claims) == 1  # one claim (epoch 0) per loop, across both runs


def test_a_variant_changes_the_spec_only(tmp_path):
    """variant_of names another loop with the same plant, dt and structure; anything else is refused."""
    from tuner.studies.schema import InvalidStudyError, load_study

    base = ('name = "v"\n[[loop]]\nname = "a"\nplant = "1/(s+1)"\ndt = 0.1\nstructure = "pi"\n'
            '[[loop]]\nname = "b"\nvariant_of = "a"\nplant = "1/(s+1)"\ndt = 0.1\nstructure = "{st}"\n'
            'spec = {{ms_max = 1.4}}\n')
    ok = tmp_path / "ok.toml"
    ok.write_text(base.format(st="pi"))
    assert [lp.name for lp in load_study(ok).loop] == ["a", "b"]
    bad = tmp_path / "bad.toml"
    bad.write_text(base.format(st="pid"))
    with pytest.raises(InvalidStudyError, match="differs in structure"):
        load_study(bad)


@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_cascade_says_when_its_between_samples_simulation_did_not_run():
    """Issue 30: an inner plant with a delay: the whole cascade's simulation needs delay-free plants and is skipped;
    the report says so (it said the simulation ran)."""
    from tuner import tune
    from tuner.analysis.cascade import EXACT_NOTE, SKIPPED_NOTE
    from tuner.studies.evaluate import evaluate_loop, loop_plants

    def note_for(pitch_delay):
        st = parse_study(_study(l0={"delay": pitch_delay} if pitch_delay else {}))
        inner = tune(loop_plants(st, st.get("pitch"), {})[0], structure="pid_z", dt=0.04, seed=0).controller
        outer_plant = loop_plants(st, st.get("x"), {"pitch": inner})[0]
        outer = tune(outer_plant, structure="lead", dt=0.04, seed=0).controller
        ev = evaluate_loop(st, st.get("x"), outer, {"pitch": inner, "x": outer})
        assert ev.nominal.metrics.stable
        return ev.cascade, ev.cascade_note

    sim, note = note_for(0.0)
    assert note == EXACT_NOTE and sim is not None
    sim, note = note_for(0.02)
    assert note == SKIPPED_NOTE and sim is None
