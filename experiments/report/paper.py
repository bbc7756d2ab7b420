"""The paper's numbers the report sets beside ours, in one place: nothing else in `experiments.report` types one.

Each constant is copied from the paper (Keyframe-Focused Visual Imitation Learning) or its supplement; the report
reads them, never edits them. A task's own published main-metric results (the supplement's Table 4, e.g. a
driving success rate) live in its record instead (`ape_jax.tasks.Task.paper`), beside the rest of the task.

- `PAPER_TABLE5`: the supplement's Table 5 (MuJoCo-State, its own experts, 300k iterations), mean returns per
  method and task;
- `PAPER_STEP`: the step weighting's setting the paper reports (THR 10%, W 5), and `PAPER_STEP_LABEL`, how
  tables name Ours at it;
- `PAPER_TAU`: the paper's softmax temperature per task;
- `PAPER_SENSITIVITY_TAU`, `PAPER_SENSITIVITY_W`: the supplement's §4 sensitivity study (its W at the
  step setting's THR);
- `PAPER_DRIVING_TABLES`: which of the supplement's driving tables (CARLA, NoCrash-Dense) each of the suite's
  driving protocols stands for: Table 1 with the car's speed in view, Table 2 without it.
"""

from __future__ import annotations

# The supplement's Table 5 (MuJoCo-State; its own experts, 300k iterations): mean returns.
PAPER_TABLE5 = {
    "bc-so": {"hopper": 275, "halfcheetah": -38, "walker2d": 363},
    "bc-oh": {"hopper": 293, "halfcheetah": 820, "walker2d": 592},
    "fca": {"hopper": 1086, "halfcheetah": 1250, "walker2d": 1296},
    "ours": {"hopper": 641, "halfcheetah": 1023, "walker2d": 1460},
}
PAPER_STEP = {"thr": 0.1, "w": 5.0}  # the setting the paper reports for its step weighting
# How tables label Ours at that setting: "Ours, step THR 10% W 5".
PAPER_STEP_LABEL = f"Ours, step THR {100 * PAPER_STEP['thr']:g}% W {PAPER_STEP['w']:g}"
PAPER_TAU = {"hopper": 0.2, "walker2d": 0.2, "halfcheetah": 0.1}  # the paper's softmax τ per environment
# The supplement's §4 sensitivity study: Walker2d returns (mean, std) per softmax τ, and CARLA driving success (%)
# per step W (at THR 10%).
PAPER_SENSITIVITY_TAU = {0.1: (765, 103), 0.2: (769, 97), 0.5: (724, 61)}
PAPER_SENSITIVITY_W = {4.0: 41.9, 5.0: 43.4, 6.0: 41.3}
# The supplement's driving tables (CARLA's NoCrash-Dense; its Table 3 is the loss analysis): per protocol of the
# suite's driving family (`ape_jax.tasks.FAMILIES["nocrash"]`), the table's number and what sets it apart.
PAPER_DRIVING_TABLES = {"nocrash": (1, "NoCrash-Dense, speed in view"),
                        "nocrash-nospeed": (2, "NoCrash-Dense without the speed")}
