# Table 2 (arm rows) at the paper's LL budget (1.2M env steps) as grouped bars: RESULTS.md, "Table 2".
E=experiments/results/table2_evals
PYTHONPATH=. python experiments/studies/bars.py --out experiments/results/table2_1p2m \
  --title "Table 2 (arm rows) at the paper's budgets: A's 500k-decision HL zero-shot over the 3Link LL, 1.2M env steps (hdt's default alignment)" \
  "PM→3Link BP1|plain|0.17=$E/pm_arm3_push1_1p2m.json#plain1p2m|PM500k" \
  "PM→3Link BP1|aligned|0.34=$E/pm_arm3_push1_1p2m.json#aligned1p2m|PM500k" \
  "PM→3Link BP2|plain|0.24=$E/pm_arm3_push2_1p2m.json#plain1p2m|PM500k" \
  "PM→3Link BP2|aligned|0.43=$E/pm_arm3_push2_1p2m.json#aligned1p2m|PM500k" \
  "2Link→3Link BP1|plain|0.20=$E/arm2_arm3_push1_1p2m.json#plain1p2m|2Link" \
  "2Link→3Link BP1|aligned|0.43=$E/arm2_arm3_push1_1p2m.json#aligned1p2m|2Link" \
  "2Link→3Link BP2|plain|0.61=$E/arm2_arm3_push2_1p2m.json#plain1p2m|2Link" \
  "2Link→3Link BP2|aligned|0.42=$E/arm2_arm3_push2_1p2m.json#aligned1p2m|2Link" "$@"
