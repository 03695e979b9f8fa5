"""The report's verdict: safety first, each claim with its interval; a less safe policy is
never called better, however fast."""

from __future__ import annotations

import pandas as pd

from tap_bench.bench.scores.verdict import verdict_lines, verdict_table


def _pm(policy: str, rows: dict[str, tuple[float, float, float]], env: str = "all"):
    better = {"crashed": False, "mean_speed": True, "min_headway_s": True, "min_ttc_s": True,
              "rms_jerk": False}
    return [{"env": env, "measure": m, "higher_is_better": better[m], "diff": d,
             "diff_low": lo, "diff_high": hi, "policy_a": policy, "policy_b": "idm"}
            for m, (d, lo, hi) in rows.items()]


def test_a_fast_crashing_policy_reads_less_safe_with_its_intervals():
    rows = _pm("random", {"crashed": (0.61, 0.5, 0.7), "min_ttc_s": (-4.0, -5.0, -3.0),
                          "min_headway_s": (-1.0, -1.5, -0.5), "mean_speed": (2.0, 1.0, 3.0),
                          "rms_jerk": (5.0, 4.0, 6.0)})
    rows += _pm("idm-defensive", {"crashed": (-0.05, -0.12, 0.02),
                                  "min_ttc_s": (0.5, 0.1, 0.9),
                                  "min_headway_s": (0.3, -0.1, 0.7),
                                  "mean_speed": (-2.0, -2.5, -1.5),
                                  "rms_jerk": (-1.0, -1.5, -0.5)})
    rows += _pm("idm-copy", {m: (0.0, -0.1, 0.1) for m in ("crashed", "min_ttc_s",
                                                          "min_headway_s", "mean_speed",
                                                          "rms_jerk")})
    rows += _pm("random", {"crashed": (0.9, 0.8, 0.97)}, env="highway")
    labels = pd.DataFrame([{"env": "merge", "label": "Left Merge | Accelerate",
                            "diff": 0.5, "diff_low": 0.3, "diff_high": 0.7,
                            "policy_a": "random", "policy_b": "idm"},
                           {"env": "merge", "label": "Straight | Cruise", "diff": 0.05,
                            "diff_low": -0.1, "diff_high": 0.2, "policy_a": "random",
                            "policy_b": "idm"}])
    paired = pd.DataFrame([{"env": "all", "policy_a": "random", "policy_b": "idm",
                            "n_pairs": 30, "agreement": 0.1, "agreement_low": 0.03,
                            "agreement_high": 0.26}])
    table = verdict_table(pd.DataFrame(rows), paired, labels)
    overall = table.groupby("policy")["overall"].first()
    assert overall["random"] == "less safe"  # faster, but safety comes first
    assert overall["idm-defensive"] == "safer"
    assert overall["idm-copy"].startswith("as safe as far as the seeds show")
    random = table[table["policy"] == "random"].set_index("area")
    assert "crash rate +61.00 points [+50.00, +70.00] (pooled)" in random.loc["safety",
                                                                             "evidence"]
    assert "(highway)" in random.loc["safety", "evidence"]
    assert random.loc["efficiency", "word"] == "faster, harsher"
    assert "'Left Merge | Accelerate' +50 points [+30, +70] (merge)" in \
        random.loc["behaviour", "evidence"]
    assert "Straight | Cruise" not in random.loc["behaviour", "evidence"]  # not clear of 0
    assert "same label on 10 % [3, 26] of the seeds" in random.loc["behaviour", "evidence"]
    lines = verdict_lines(table)
    assert lines[0] == "random vs idm: LESS SAFE"
    assert verdict_table(pd.DataFrame()).empty
