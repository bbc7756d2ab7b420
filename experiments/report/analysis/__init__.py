"""The report's numbers: results files loaded and merged, the rows each table picks, the differences, the weights.

Nothing here formats markdown or draws: `experiments.report.sections` and `experiments.report.figures` do, from
what these functions return. One module per concern, each re-exported here:

- `encoders`: the `Key` part of frames seen through a pretrained perception encoder (`perception_of`), and its words;
- `groups`: `load` one results file, `check_references`, `merge` them per `Key(env, obs, protocol, budget)` (an
  expert other than the task's own, or raw labels, a group of its own), the groups in report order and their
  titles;
- `selection`: method labels, the rows each table picks (`method_rows`, `best_of`, `paper_step_row`,
  `headline`, ...), per-seed values (`seed_values`), the paper's settings against the grid (`choices`), longer
  runs, a driving group's table and rows (`driving_table`, `driving_rows`);
- `differences`: `mean_difference`, `mean_estimate`, `verdict`, and per group BC-OH − BC-SO and Ours − BC-OH
  (`difference_rows`); the paper's comparisons in a driving group (`driving_comparisons`);
- `diagnostics`: copycat diagnostics per configuration, at the end and over training;
- `driving`: a driving task's verdict across its driving groups (`driving_verdicts`), for the results page;
- `copycat`: the copycat map (`copycat_map`) and the extended map (`extended_map`);
- `recipe`: the recipe comparison (mlp against bn-mlp) and the paper's budget beside Table 5;
- `ranking`: the later methods (`LATER`) ranked with the paper's per family of cells (where copying is
  expected, the default tasks): IQM, probability of improvement over BC-OH, per-cell differences and copycat counts;
  and the on-policy check (`onpolicy_check`: DAgger and HistoryDropout against BC-OH where copying is expected);
- `regime`: Table 5 with FCA's expert (an imported expert or raw labels under the paper's protocol and recipe):
  every configuration against BC-OH and beside Table 5, with its copycat diagnostics (`regime_table`);
- `rates`: the numbers of a rate-judged task's reading (`rate_reading`);
- `weights`: how concentrated each weighting is within a batch (`weight_shares`).

The paper's own numbers are in `experiments.report.paper`.
"""

from experiments.report.analysis.differences import (DRIVING_COMPARISONS, Comparison, Difference, Interval,
                                                     RecipeCell, Share, difference_rows, difference_unit,
                                                     driving_comparisons, gap_share, history_difference,
                                                     history_share, mean_cell, mean_difference, mean_estimate,
                                                     ours_differences, verdict, versus_bcoh)
from experiments.report.analysis.copycat import (MAP_METHODS, CopycatMap, MapCell, MapPoint, MapRow, copycat_map,
                                                 extended_map)
from experiments.report.analysis.diagnostics import (DiagnosticsRow, PolicyDiagnostics, Spread, TrainingPoint,
                                                     diagnostics_block, diagnostics_rows, diagnostics_thresholds,
                                                     has_diagnostics, policy_diagnostics, recipe_diagnostics, run_at,
                                                     spread, training_points)
from experiments.report.analysis.driving import CAMERA, DrivingVerdict, driving_verdicts
from experiments.report.analysis.encoders import encoder_stem, encoder_words, perception_of
from experiments.report.analysis.groups import (BRAX, STATE, STATE_TRAIN, FIRST_IMAGE_PRESET, MUJOCO, Group, Key,
                                                Merged, ReportError, Source, budget_of, check_references, config_key,
                                                demonstrator, expert_part, expert_words, file_stem,
                                                former_preset, group_title, groups_of, raw_labels,
                                                in_state_family, is_rate, load, main_metric, merge, ordered,
                                                other_history, other_setting, protocol_of, protocol_words, protocols_of,
                                                variant_name)
from experiments.report.analysis.rates import LEARNED, Estimate, RateReading, per_seed, rate_reading
from experiments.report.analysis.recipe import (BUDGET_METHODS, RECIPE_METHODS, AlphaRow, BudgetPoint, BudgetRow,
                                                RecipeRow, alpha_rows, budget_differences, budget_rows,
                                                paper_budget_groups, recipe_groups, recipe_rows)
from experiments.report.analysis.ranking import (LATER, ONPOLICY, RANKED, CellResult, Check, Family, Ranked,
                                                 is_copycat_cell, onpolicy_check, ranking, ranking_cells)
from experiments.report.analysis.regime import (REGIME_METHODS, RegimeRow, RegimeTable, cell_title, is_regime,
                                                regime_budget_groups, regime_groups, regime_table)
from experiments.report.analysis.selection import (CEILING, CEILING_LABEL, DRIVING_ORDER, Choice, DrivingRow,
                                                   DrivingTable, Gap, LongerRow, Shift, best_of, choices, comparisons,
                                                   copycat_groups, display_metric, driving_rows, driving_table,
                                                   expert_ape,
                                                   extra_methods, first_training, gap, has_ceiling, headline,
                                                   hparams_suffix, retrained_shift,
                                                   is_finite, is_number, known_methods,
                                                   label, longer_runs, loss_rows, method_rows, metric_value,
                                                   ok_runs, paper_step_row, percent, seed_values, sensitivity,
                                                   setting_words, task_metric_rows, thousands)
from experiments.report.analysis.weights import (APE_SCALES, WeightShares, ape_mean, quantile_mean, raw_quantiles,
                                                 weight_shares)

__all__ = [
    "LATER", "ONPOLICY", "RANKED", "CellResult", "Check", "Family", "Ranked", "is_copycat_cell", "onpolicy_check",
    "ranking", "ranking_cells",
    "REGIME_METHODS", "RegimeRow", "RegimeTable", "cell_title", "is_regime", "regime_budget_groups",
    "regime_groups", "regime_table",
    "check_references", "demonstrator", "expert_part", "expert_words", "raw_labels",
    "CEILING", "CEILING_LABEL", "Share", "gap_share", "has_ceiling", "history_share",
    "CAMERA", "DRIVING_COMPARISONS", "DRIVING_ORDER", "Comparison", "DrivingRow", "DrivingTable", "DrivingVerdict",
    "driving_comparisons", "driving_rows", "driving_table", "driving_verdicts", "setting_words",
    "APE_SCALES", "LEARNED", "Estimate", "RateReading", "per_seed", "rate_reading",
    "BRAX", "BUDGET_METHODS", "STATE", "STATE_TRAIN", "FIRST_IMAGE_PRESET", "former_preset",
    "MAP_METHODS", "MUJOCO", "RECIPE_METHODS", "AlphaRow", "BudgetPoint", "BudgetRow", "Choice", "CopycatMap",
    "DiagnosticsRow", "Difference", "Gap", "Group", "Interval", "Key", "LongerRow", "MapCell", "MapPoint", "MapRow",
    "Merged", "PolicyDiagnostics", "RecipeCell", "RecipeRow", "ReportError", "Source", "Spread", "TrainingPoint",
    "Shift", "first_training", "retrained_shift",
    "WeightShares", "alpha_rows", "ape_mean", "best_of", "mean_difference", "mean_estimate", "difference_rows",
    "difference_unit", "budget_differences", "budget_of", "budget_rows", "choices", "comparisons", "config_key",
    "copycat_groups", "copycat_map", "diagnostics_block", "diagnostics_rows", "diagnostics_thresholds",
    "display_metric", "encoder_stem", "encoder_words", "expert_ape", "extended_map", "extra_methods", "file_stem",
    "gap", "group_title", "perception_of",
    "groups_of", "has_diagnostics", "headline", "history_difference", "hparams_suffix", "in_state_family", "is_finite",
    "is_number", "is_rate", "known_methods", "label", "load", "longer_runs", "loss_rows", "main_metric", "mean_cell",
    "merge", "method_rows", "metric_value", "ok_runs", "ordered", "other_history", "other_setting",
    "ours_differences", "paper_budget_groups", "paper_step_row", "percent", "policy_diagnostics", "protocol_of",
    "protocol_words", "protocols_of", "quantile_mean", "raw_quantiles", "recipe_diagnostics", "recipe_groups",
    "recipe_rows", "run_at", "seed_values", "sensitivity", "spread", "task_metric_rows", "thousands",
    "training_points", "variant_name", "verdict", "versus_bcoh", "weight_shares",
]
