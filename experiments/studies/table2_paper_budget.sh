# Table 2 (arm rows) at the paper-budget settings as grouped bars: RESULTS.md, "Appendix cells" (400k LL env steps). Extra bars as arguments.
E=experiments/results/table2_evals
PYTHONPATH=. python experiments/studies/bars.py --out experiments/results/table2_paper_budget \
  --title "Table 2 (arm rows): PM HL / 2Link HL zero-shot over the 3Link LL, 400k env steps (discriminator lr 2e-4, w0 0.3 unless named)" \
  "PM→3Link BP1|plain|0.17=$E/pm_arm3_push1_offline_llstart.json#plain|PM" \
  "PM→3Link BP1|aligned, offline (A restarts at LL start)|0.35=$E/pm_arm3_push1_offline_llstart.json#aligned|PM" \
  "PM→3Link BP1|aligned, offline (A restarts at HL start)|0.35=$E/pm_arm3_push1_offline_hlstart.json#success" \
  "2Link→3Link BP1|plain|0.20=$E/arm2_push1_500k_matrix.json#3Link400k|2Link" \
  "2Link→3Link BP1|aligned, offline (A restarts at LL start)|0.49=$E/arm2_push1_500k_matrix.json#3Link400k_aligned|2Link" \
  "PM→3Link BP2|plain|0.24=$E/pm_push2_500k_matrix.json#3Link400k|PM" \
  "PM→3Link BP2|aligned, offline (A restarts at LL start)|0.43=$E/pm_push2_500k_matrix.json#3Link400k_alignedPM|PM" \
  "PM→3Link BP2|aligned, offline (A restarts at HL start)|0.43=$E/pm_arm3_push2_offline_hlstart.json#success" \
  "PM→3Link BP1|aligned, online|0.34=$E/pm_arm3_push1_online_navvalues.json#success" \
  "PM→3Link BP2|aligned, online|0.43=$E/pm_arm3_push2_online_navvalues.json#success" \
  "PM→3Link BP1|aligned, online, paper's manip. values (lr 3e-4, w0 0.4)|0.34=$E/pm_arm3_push1_online_papervalues.json#success" \
  "PM→3Link BP2|aligned, online, paper's manip. values (lr 3e-4, w0 0.4)|0.43=$E/pm_arm3_push2_online_papervalues.json#success" \
  "2Link→3Link BP1|aligned, online, paper's manip. values (lr 3e-4, w0 0.4)|0.43=$E/arm2_arm3_push1_online_papervalues.json#success" \
  "2Link→3Link BP2|plain|0.61=$E/arm2_push2_500k_matrix.json#plain|2Link" \
  "2Link→3Link BP2|aligned, offline (A restarts at LL start)|0.42=$E/arm2_push2_500k_matrix.json#offline|2Link" \
  "2Link→3Link BP2|aligned, online, paper's manip. values (lr 3e-4, w0 0.4)|0.42=$E/arm2_push2_500k_matrix.json#online|2Link" "$@"
