"""Issue 39's head-to-head: the tuner's px4_rate / ardupilot_rate designs against the firmwares' own autotunes.

Modules (all written here from the firmware sources named in each docstring, independent of ``tuner``'s law code):

- :mod:`h2h.airframes`: the five airframes (continuous plants, gyro filters, loop and raw gyro rates);
- :mod:`h2h.laws`: PX4's and ArduPilot's rate laws, one sample per call, and their linear matrices;
- :mod:`h2h.sim`: the plant and sensor chain lifted to the loop rate (the raw-rate filters and the PX4 D path
  propagated sample by sample over one loop period with the input held), the per-sample closed loop;
- :mod:`h2h.metrics`: PM, GM, DRB from the lifted loop, overshoot/settling/load figures from the flown loop;
- :mod:`h2h.px4_autotune`: PX4's mc_autotune_attitude_control (excitation, prefilters, ARX RLS, GMVC) ported;
- :mod:`h2h.ap_autotune`: ArduPilot's AC_AutoTune_Multi twitch tuning emulated;
- :mod:`h2h.ours`: the tuner's designs (pluggable);
- :mod:`h2h.checks`: the sanity checks (laws against tuner's transfer functions, GMVC by hand).

``bench/autotune_h2h.py`` is the command line.
"""
