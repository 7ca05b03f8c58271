"""Issue 39's head-to-head: the tuner's px4_rate / ardupilot_rate designs against PX4's and ArduPilot's autotunes.

    .venv/bin/python bench/autotune_h2h.py                       # everything (see the report for the time)
    .venv/bin/python bench/autotune_h2h.py --airframes quad400,hexa250 --designers px4_autotune,ours_px4
    .venv/bin/python bench/autotune_h2h.py --tune-kw '{"effort": "fast"}' --out /tmp/h2h

Five airframes (:mod:`h2h.airframes`: a 400 Hz quad, a 1 kHz racer, a 250 Hz large hexacopter, a pure integrator
plus motor lag, a flexible frame with a 40 rad/s mode), each flown with the firmware's own law simulated per
sample from the sources (:mod:`h2h.sim`, :mod:`h2h.laws`: PX4's D term on every raw gyro sample), by these
designers:

- ``px4_default`` / ``ap_default``: the firmware's default gains;
- ``px4_autotune``: PX4's mc_autotune_attitude_control ported (:mod:`h2h.px4_autotune`: its excitation flown in
  closed loop, its prefilters and ARX RLS, GMVC on the converged model);
- ``ap_autotune``: ArduPilot's AutoTune emulated (:mod:`h2h.ap_autotune`: the twitches and their gain updates);
- ``ours_px4`` / ``ours_ap``: ``tuner.tune(..., structure="px4_rate" | "ardupilot_rate")`` with the default spec
  and effort (:func:`h2h.ours.ours`); ``ours_px4_iae`` / ``ours_ap_iae``: the same with ``objective="iae"``.

Every design is judged by :func:`h2h.metrics.evaluate` on the airframe and at 0.8x / 1.25x control effectiveness.
The targets of issue 39 are checked for ``ours_px4`` and ``ours_ap`` and printed pass/fail. Writes
``<out>.md`` and ``<out>.json`` (default ``bench/results/autotune_h2h``). Nothing here is asserted.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import platform
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for p in (str(HERE), str(ROOT)):
    if p not in sys.path:
        sys.path.insert(0, p)

from h2h.airframes import AIRFRAMES, Airframe, get_airframe  # noqa: E402
from h2h.laws import AP_DEFAULTS, PX4_DEFAULTS  # noqa: E402
from h2h.metrics import evaluate  # noqa: E402

FIRMWARE = {"px4_default": "px4", "px4_autotune": "px4", "ours_px4": "px4", "ours_px4_iae": "px4",
            "ap_default": "ardupilot", "ap_autotune": "ardupilot", "ours_ap": "ardupilot", "ours_ap_iae": "ardupilot"}
DESIGNERS = tuple(FIRMWARE)
OURS = {"ours_px4": ("px4_rate", {}), "ours_px4_iae": ("px4_rate", {"objective": "iae"}),
        "ours_ap": ("ardupilot_rate", {}), "ours_ap_iae": ("ardupilot_rate", {"objective": "iae"})}
SCALES = (0.8, 1.25)


def _start(af: Airframe, firmware: str) -> dict:
    """The vehicle's gains before the autotune: the firmware defaults, scaled where they are not flyable."""
    if af.start_scale == 1.0:
        return {}
    if firmware == "px4":
        return {"K": af.start_scale}
    return {k: AP_DEFAULTS[k] * af.start_scale for k in ("P", "I", "D")}


def _ours_task(name: str, airframe: str, designer: str, tune_kw: dict) -> tuple:
    from h2h.ours import ours

    law, kw = OURS[designer]
    try:
        return name, ours(AIRFRAMES[airframe], law, **{**kw, **tune_kw}), None
    except Exception as exc:  # report it (with where it was raised); the bench goes on
        import traceback

        where = traceback.extract_tb(exc.__traceback__)[-1]
        return name, None, f"{type(exc).__name__}: {exc} (raised at {Path(where.filename).name}:{where.lineno})"


def _design(af: Airframe, designer: str, turbulence: float) -> dict:
    t0 = time.perf_counter()
    if designer == "px4_default":
        return {"ok": True, "gains": dict(PX4_DEFAULTS), "wall_s": 0.0}
    if designer == "ap_default":
        return {"ok": True, "gains": dict(AP_DEFAULTS), "wall_s": 0.0}
    if designer == "px4_autotune":
        from h2h.px4_autotune import px4_autotune

        r = px4_autotune(af, _start(af, "px4"), turbulence=turbulence)
        return {"ok": r.ok, "gains": r.gains, "reason": r.reason, "wall_s": time.perf_counter() - t0,
                "start": _start(af, "px4"),
                "model": {"num": r.model_num, "den": r.model_den, "dt": r.model_dt,
                          "identified_s": r.identified_s, "variances": r.variances},
                "kid": list(r.kid), "att_p": r.att_p}
    if designer == "ap_autotune":
        from h2h.ap_autotune import ap_autotune

        r = ap_autotune(af, _start(af, "ardupilot"))
        return {"ok": r.ok, "gains": r.gains, "reason": r.reason, "wall_s": time.perf_counter() - t0,
                "start": _start(af, "ardupilot"), "angle_p": r.angle_p, "twitches": r.twitches}
    raise ValueError(designer)


def _tuner_view(af: Airframe, designer: str, gains: dict) -> dict:
    from h2h.ours import tuner_view

    law = "px4_rate" if FIRMWARE[designer] == "px4" else "ardupilot_rate"
    try:
        return tuner_view(af, law, gains)
    except Exception as exc:  # the tuner refuses or fails: say so in the table
        return {"error": f"{type(exc).__name__}: {exc}"}


def _tree_id() -> dict:
    """Which tuner the figures are of: HEAD, whether tuner/ has uncommitted edits, a hash of its sources."""
    import hashlib

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True,
                                  check=False).stdout.strip()
        except OSError:
            return ""

    h = hashlib.sha256()
    for f in sorted((ROOT / "tuner").rglob("*.py")):
        h.update(f.read_bytes())
    return {"head": git("rev-parse", "--short", "HEAD") or "?", "tuner_edits": len(git("status", "--short", "tuner")
                                                                                     .splitlines()),
            "tuner_sha256": h.hexdigest()[:12]}


def _figures(af: Airframe, fw: str, gains: dict) -> dict:
    out = {"nominal": evaluate(af, fw, gains).to_dict()}
    for k in SCALES:
        out[f"x{k}"] = evaluate(af.scaled(k), fw, gains).to_dict()
    return out


# -- the targets -----------------------------------------------------------------------------------------------
def _breaks_spec(f: dict) -> bool:
    return not f["stable"] or f["overshoot_pct"] > 10 or f["pm_deg"] < 55 or f["gm_db"] < 6


def _usable(d: dict | None) -> bool:
    return bool(d and d.get("ok") and d.get("figures") and d["figures"]["nominal"]["stable"])


def targets(res: dict, airframe: str, ours_name: str) -> dict:
    """Issue 39's targets for one of our default designs on one airframe."""
    row = res[airframe].get(ours_name)
    fw = FIRMWARE[ours_name]
    same, other = ("px4_autotune", "ap_autotune") if fw == "px4" else ("ap_autotune", "px4_autotune")
    ref_name = same if _usable(res[airframe].get(same)) else other if _usable(res[airframe].get(other)) else None
    out: dict = {"reference": ref_name}
    if not row or not row.get("ok"):
        out["error"] = (row or {}).get("reason", "not run")
        return out
    f = row["figures"]["nominal"]
    if ref_name:
        rf = res[airframe][ref_name]["figures"]["nominal"]
        brk = _breaks_spec(rf)
        factor = 1.25 if brk else 1.0
        out["reference_breaks_spec"] = brk
        out["factor"] = factor
        tol = 1 + 1e-9
        ok_rec = f["stable"] and f["load_recovery_s"] <= factor * rf["load_recovery_s"] * tol
        out["load_recovery"] = {"ours": f["load_recovery_s"], "ref": rf["load_recovery_s"], "pass": bool(ok_rec)}
        out["settling"] = {"ours": f["settling_s"], "ref": rf["settling_s"],
                           "pass": bool(f["stable"] and f["settling_s"] <= factor * rf["settling_s"] * tol)}
    out["overshoot"] = {"ours": f["overshoot_pct"], "pass": bool(f["stable"] and f["overshoot_pct"] <= 10)}
    out["pm"] = {"ours": f["pm_deg"], "pass": bool(f["stable"] and f["pm_deg"] >= 55)}
    out["gm"] = {"ours": f["gm_db"], "pass": bool(f["stable"] and f["gm_db"] >= 6)}
    for k in SCALES:
        g = row["figures"][f"x{k}"]
        ok = bool(g["stable"] and math.isfinite(g["settling_s"]) and g["overshoot_pct"] <= 15 and g["pm_deg"] >= 45)
        out[f"x{k}"] = {"stable": g["stable"], "settling_s": g["settling_s"], "overshoot_pct": g["overshoot_pct"],
                        "pm_deg": g["pm_deg"], "pass": ok}
    return out


# -- text ------------------------------------------------------------------------------------------------------
def _g(x: float, nd: int = 3) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "nan"
    if isinstance(x, float) and math.isinf(x):
        return "inf"
    if abs(x) < 1e-12:
        return "0"
    return f"{x:.{nd}g}"


def _gains_text(fw: str, g: dict | None) -> str:
    if not g:
        return "-"
    s = f"P {_g(g['P'])} I {_g(g['I'])} D {_g(g['D'])} FF {_g(g.get('FF', 0.0))}"
    if fw == "px4" and abs(g.get("K", 1.0) - 1.0) > 1e-12:
        s += f" K {_g(g['K'])}"
    return s


def _rob(f: dict) -> str:
    if not f["stable"]:
        return "unstable"
    st = "yes" if math.isfinite(f["settling_s"]) else "no"
    return f"{st} / {_g(f['overshoot_pct'], 2)} / {_g(f['pm_deg'], 3)}"


def markdown(res: dict, meta: dict, tgt: dict, checks: dict | None) -> str:
    L = ["# Issue 39: the firmware laws' autotunes against the tuner (bench/autotune_h2h.py)", "",
         f"Tree {meta['commit']} with {meta['tuner_edits']} uncommitted file(s) under tuner/ (sources sha256 "
         f"{meta['tuner_sha256']}{'; they changed during the run' if meta['tuner_changed_during_run'] else ''}), "
         f"{meta['when']}, "
         f"{meta['machine']}; run {meta['wall_s']:.0f} s with {meta['jobs']} worker(s). Command: "
         f"`{meta['command']}`.", "",
         "Each design flown on the firmware's law simulated per sample from its sources (PX4: D on every raw gyro "
         "sample); PM/GM/DRB from the exact lifted loop, overshoot and 2 % settling of a 1 rad/s step on the true "
         "rate at the IMU between samples, load: 0.2 torque step at the plant input (recovery: until |w| stays "
         "within 10 % of its peak). Robustness columns: control effectiveness x0.8 and x1.25: settles / "
         "overshoot % / PM deg.", "",
         "| airframe | designer | gains | PM deg | GM dB | OS % | settle s | DRB rad/s | load peak rad/s | "
         "load rec s | x0.8 | x1.25 |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for an, rows in res.items():
        for dn, d in rows.items():
            fw = FIRMWARE[dn]
            if not d.get("ok"):
                L.append(f"| {an} | {dn} | failed: {d.get('reason', '?')} | | | | | | | | | |")
                continue
            f = d["figures"]["nominal"]
            if not f["stable"]:
                L.append(f"| {an} | {dn} | {_gains_text(fw, d['gains'])} | unstable | | | | | | | "
                         f"{_rob(d['figures']['x0.8'])} | {_rob(d['figures']['x1.25'])} |")
                continue
            L.append(f"| {an} | {dn} | {_gains_text(fw, d['gains'])} | {_g(f['pm_deg'])} | {_g(f['gm_db'])} | "
                     f"{_g(f['overshoot_pct'], 2)} | {_g(f['settling_s'])} | {_g(f['drb_rad_s'])} | "
                     f"{_g(f['load_peak'])} | {_g(f['load_recovery_s'])} | {_rob(d['figures']['x0.8'])} | "
                     f"{_rob(d['figures']['x1.25'])} |")
    has_tgt = any(per for per in tgt.values())
    has_ours = any(dn in OURS for rows in res.values() for dn in rows)
    L += ["", "## Targets for the tuner's default designs (ours_px4, ours_ap)", "",
          "Reference: the same firmware's autotune, the other firmware's where it failed or is unstable. Where the "
          "reference breaks the spec (overshoot > 10 %, PM < 55 deg or GM < 6 dB) ours must be within 25 % of its "
          "recovery and settling, otherwise no slower.", "",
          "| airframe | design | reference (breaks spec) | load rec ours/ref | settling ours/ref | OS <= 10 | "
          "PM >= 55 | GM >= 6 | x0.8 | x1.25 |", "|---|---|---|---|---|---|---|---|---|---|"]

    def pf(x: dict | None) -> str:
        return "-" if not x else ("PASS" if x["pass"] else "FAIL")

    for an, per in tgt.items():
        for dn, t in per.items():
            if "error" in t:
                L.append(f"| {an} | {dn} | {t.get('reference')} | error: {t['error']} | | | | | | |")
                continue
            ref = f"{t['reference']} ({'yes' if t.get('reference_breaks_spec') else 'no'})" if t["reference"] else \
                "none usable"
            lr = (f"{pf(t.get('load_recovery'))} {_g(t['load_recovery']['ours'])}/{_g(t['load_recovery']['ref'])}"
                  if "load_recovery" in t else "-")
            st = (f"{pf(t.get('settling'))} {_g(t['settling']['ours'])}/{_g(t['settling']['ref'])}"
                  if "settling" in t else "-")
            L.append(f"| {an} | {dn} | {ref} | {lr} | {st} | {pf(t['overshoot'])} {_g(t['overshoot']['ours'], 2)} | "
                     f"{pf(t['pm'])} {_g(t['pm']['ours'])} | {pf(t['gm'])} {_g(t['gm']['ours'])} | "
                     f"{pf(t['x0.8'])} | {pf(t['x1.25'])} |")
    passed = sum(v["pass"] for per in tgt.values() for t in per.values() for k, v in t.items()
                 if isinstance(v, dict) and "pass" in v)
    total = sum(1 for per in tgt.values() for t in per.values() for k, v in t.items()
                if isinstance(v, dict) and "pass" in v)
    L += ["", f"Targets passed: {passed} of {total}.", ""]
    if not has_tgt:  # no default design of ours in this run: no targets
        L = L[:L.index("## Targets for the tuner's default designs (ours_px4, ours_ap)") - 1]
        L.append("")
    # the tuner's designs, and the tuner's model of every design against the law as flown
    if has_ours:
        L += ["## The tuner's designs", "",
              "Wall time of each tune in its worker (the machine's other load included), of which NLP builds; "
              "`budget`: the search stopped on its time budget (not converged).", "",
              "| airframe | design | objective | tune wall s (builds) | stop | meets spec (tuner) | on a bound / "
              "limit |",
              "|---|---|---|---|---|---|---|"]
    for an, rows in res.items():
        for dn, d in rows.items():
            if dn in OURS and d.get("ok"):
                sv = d.get("solver") or {}
                L.append(f"| {an} | {dn} | {d.get('objective')} | {d['wall_s']:.1f} ({_g(sv.get('build_s'))}) | "
                         f"{sv.get('stop')} | {d['meets_spec']} | {'; '.join(d.get('at_bounds') or []) or '-'} |")
    L += ["", "## The tuner's model of the law against the law as flown", "",
          "The tuner's verifier (`tuner.analyze` with `get_structure(law).tf(gains, dt)`: D path at the loop rate, "
          "continuous gyro low-pass) against this bench (raw-rate sensor chain, PX4's D on every raw sample).", "",
          "| airframe | design | PM tuner / flown | GM tuner / flown | OS % tuner / flown | settling s tuner / flown |",
          "|---|---|---|---|---|---|"]
    for an, rows in res.items():
        for dn, d in rows.items():
            tv = d.get("tuner_view")
            if not d.get("ok") or not tv:
                continue
            f = d["figures"]["nominal"]
            if "error" in tv:
                L.append(f"| {an} | {dn} | {tv['error']} | | | |")
                continue
            L.append(f"| {an} | {dn} | {_g(tv['pm_deg'])} / {_g(f['pm_deg'])} | {_g(tv['gm_db'])} / {_g(f['gm_db'])} | "
                     f"{_g(tv['overshoot_pct'], 2)} / {_g(f['overshoot_pct'], 2)} | {_g(tv['settling_s'])} / "
                     f"{_g(f['settling_s'])} |")
    L.append("")
    extra = []
    for an, rows in res.items():
        p = rows.get("px4_autotune")
        if p and "model" in p:
            m = p["model"]
            extra.append(f"| {an} | px4_autotune | model_dt {_g(m['dt'])} s, converged after {_g(m['identified_s'])} s;"
                         f" {p.get('reason')} |")
        a = rows.get("ap_autotune")
        if a and "twitches" in a:
            extra.append(f"| {an} | ap_autotune | twitches {a['twitches']}, angle P {_g(a.get('angle_p'))}; "
                         f"{a.get('reason')} |")
    if extra:
        L += ["## The autotunes' runs", "", "| airframe | designer | run |", "|---|---|---|", *extra, ""]
    if checks:
        lv = max(c["max_rel_diff_sampled"] for c in checks["lift_vs_bruteforce"])
        lf = max(c["max_abs_diff_fine"] for c in checks["lift_vs_bruteforce"])
        lu = {st: max(c["max_rel_diff_u"] for c in checks["laws_vs_tuner"] if c["law"] == st)
              for st in ("px4_rate", "ardupilot_rate")}
        ly = {st: max(c["max_rel_diff_y"] for c in checks["laws_vs_tuner"] if c["law"] == st)
              for st in ("px4_rate", "ardupilot_rate")}
        g = checks["gmvc"]
        L += ["## Sanity checks", "",
              f"- lifted plant + sensor chain vs a brute-force raw-rate simulation (all airframes, both firmwares): "
              f"max relative difference of the sampled outputs {lv:.1e}, of the fine rate {lf:.1e} rad/s;",
              f"- the bench's PX4 law with the raw gyro rate = the loop rate vs tuner's px4_rate transfer functions "
              f"on the same sampled plant, 1 rad/s step, sample by sample: max relative difference u "
              f"{lu['px4_rate']:.1e}, y {ly['px4_rate']:.1e}; ArduPilot's law vs ardupilot_rate: u "
              f"{lu['ardupilot_rate']:.1e}, y {ly['ardupilot_rate']:.1e};",
              f"- GMVC on the hand example (h2h/checks.py): port {[round(x, 9) for x in g['port']]}, hand "
              f"{[round(x, 9) for x in g['hand']]}, max relative difference {g['max_rel_diff']:.1e}.", ""]
    return "\n".join(L)


def _jsonable(x):
    if isinstance(x, float):
        if math.isnan(x):
            return "NaN"
        if math.isinf(x):
            return "Infinity" if x > 0 else "-Infinity"
        return x
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if hasattr(x, "item"):
        return _jsonable(x.item())
    return x


def _unjson(x):
    if x == "NaN":
        return math.nan
    if x == "Infinity":
        return math.inf
    if x == "-Infinity":
        return -math.inf
    if isinstance(x, dict):
        return {k: _unjson(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_unjson(v) for v in x]
    return x


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--airframes", default=",".join(AIRFRAMES), help=f"comma list of {', '.join(AIRFRAMES)}")
    ap.add_argument("--designers", default=",".join(DESIGNERS), help=f"comma list of {', '.join(DESIGNERS)}")
    ap.add_argument("--out", default=str(HERE / "results" / "autotune_h2h"), help="output prefix (.md, .json)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes for the tuner's designs (default 2)")
    ap.add_argument("--tune-kw", default="{}", help="JSON keyword arguments added to every tuner.tune call")
    ap.add_argument("--turbulence", type=float, default=0.0,
                    help="std of the low-passed torque turbulence during PX4's identification (default 0: calm)")
    ap.add_argument("--no-checks", action="store_true", help="skip the sanity checks")
    ap.add_argument("--render", metavar="JSON", help="only write <out>.md again from a JSON this script wrote")
    a = ap.parse_args(argv)
    if a.render:
        try:
            d = _unjson(json.loads(Path(a.render).read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            print(f"--render {a.render}: {exc}", file=sys.stderr)
            return 2
        out = Path(a.out)
        out.with_suffix(".md").write_text(markdown(d["results"], d["meta"], d["targets"], d.get("checks")) + "\n")
        print(f"wrote {out.with_suffix('.md')}")
        return 0
    try:
        afs = [get_airframe(n.strip()) for n in a.airframes.split(",") if n.strip()]
        des = [d.strip() for d in a.designers.split(",") if d.strip()]
        bad = [d for d in des if d not in FIRMWARE]
        if bad:
            raise SystemExit(f"unknown designer(s) {', '.join(bad)}: give some of {', '.join(DESIGNERS)}")
        tune_kw = json.loads(a.tune_kw)
        if not isinstance(tune_kw, dict):
            raise SystemExit("--tune-kw must be a JSON object")
        if a.jobs < 1:
            raise SystemExit("--jobs must be at least 1")
    except json.JSONDecodeError as exc:
        print(f"--tune-kw is not JSON: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:
        print(exc, file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    tree = _tree_id()  # before the workers import tuner
    res: dict = {af.name: {} for af in afs}
    ours_jobs = [(af.name, d) for d in des if d in OURS for af in afs]
    pool = None
    futures = []
    if ours_jobs:
        pool = ProcessPoolExecutor(max_workers=min(a.jobs, len(ours_jobs)), mp_context=mp.get_context("spawn"))
        # one law's tunes after the other: a worker reuses the NLPs it built for the same shapes
        for an, d in sorted(ours_jobs, key=lambda x: (OURS[x[1]][0], x[1])):
            futures.append(pool.submit(_ours_task, f"{an}/{d}", an, d, tune_kw))
    for af in afs:
        for d in des:
            if d in OURS:
                continue
            r = _design(af, d, a.turbulence)
            if r.get("ok"):
                r["figures"] = _figures(af, FIRMWARE[d], r["gains"])
                r["tuner_view"] = _tuner_view(af, d, r["gains"])
            res[af.name][d] = r
            print(f"{af.name:10s} {d:13s} {_gains_text(FIRMWARE[d], r.get('gains'))}", flush=True)
    checks = None if a.no_checks else __import__("h2h.checks", fromlist=["run_checks"]).run_checks()
    for fut in futures:
        name, r, err = fut.result()
        an, d = name.split("/")
        af = get_airframe(an)
        if r is None:
            res[an][d] = {"ok": False, "reason": err}
        else:
            r["ok"] = True
            r["figures"] = _figures(af, FIRMWARE[d], r["gains"])
            r["tuner_view"] = _tuner_view(af, d, r["gains"])
            res[an][d] = r
        print(f"{an:10s} {d:13s} {_gains_text(FIRMWARE[d], res[an][d].get('gains'))} "
              f"({res[an][d].get('wall_s', math.nan):.1f} s)", flush=True)
    if pool:
        pool.shutdown()
    # designers in the requested order
    res = {an: {d: rows[d] for d in des if d in rows} for an, rows in res.items()}
    tgt = {an: {d: targets(res, an, d) for d in ("ours_px4", "ours_ap") if d in res[an]} for an in res}
    tree_end = _tree_id()
    meta = {"commit": tree["head"], "tuner_edits": tree["tuner_edits"], "tuner_sha256": tree["tuner_sha256"],
            "tuner_changed_during_run": tree_end["tuner_sha256"] != tree["tuner_sha256"],
            "when": time.strftime("%Y-%m-%d %H:%M"), "machine": f"{platform.machine()}, "
            f"{mp.cpu_count()} cpus, Python {platform.python_version()}", "wall_s": time.perf_counter() - t0,
            "jobs": a.jobs, "command": "python bench/autotune_h2h.py " + " ".join(argv if argv is not None
                                                                               else sys.argv[1:]),
            "tune_kw": tune_kw, "turbulence": a.turbulence}
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    md = markdown(res, meta, tgt, checks)
    out.with_suffix(".md").write_text(md + "\n")
    airframes = {af.name: dict(af.__dict__) for af in afs}
    out.with_suffix(".json").write_text(json.dumps(_jsonable({"meta": meta, "airframes": airframes, "results": res,
                                                              "targets": tgt, "checks": checks}), indent=1) + "\n")
    print()
    print(md)
    print(f"\nwrote {out.with_suffix('.md')} and {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
