# PM → 3Link, online discriminator data: which discriminator setting lets the PM HL transfer
# (RESULTS.md, "Appendix cells", discriminator settings). Extra bars as arguments.
E=experiments/results/table2_evals
PYTHONPATH=. python experiments/studies/bars.py --out experiments/results/disc_settings_pm_arm3 \
  --title "PM HL zero-shot over the 3Link LL aligned to the PM LL (online data, 400k env steps, 3 seeds; A's prev obs post-restart unless named): discriminator settings" \
  "BlockPush 1|plain 3Link LL|0.17=$E/pm_arm3_push1_offline_llstart.json#plain|PM" \
  "BlockPush 1|lr 2e-4, w0 0.3, every 8 (nav values)|0.34=$E/pm_arm3_push1_online_navvalues.json#success" \
  "BlockPush 1|lr 3e-4, w0 0.3, every 8|0.34=$E/pm_arm3_push1_online_w03.json#success" \
  "BlockPush 1|lr 3e-4, w0 0.4, every 8|0.34=$E/pm_arm3_push1_online_papervalues.json#success" \
  "BlockPush 1|lr 3e-4, w0 0.5 (DSAC default), every 8|0.34=$E/pm_arm3_push1_online_w05.json#success" \
  "BlockPush 1|lr 3e-4, w0 0.4, every 1 (DSAC default)|0.34=$E/pm_arm3_push1_online_ue1.json#success" \
  "BlockPush 1|lr 3e-4, w0 0.4, every 8, A's prev obs pre-restart (hdt's default)|0.34=$E/pm_arm3_push1_online_prevobs.json#success" \
  "BlockPush 2|plain 3Link LL|0.24=$E/pm_push2_500k_matrix.json#3Link400k|PM" \
  "BlockPush 2|lr 2e-4, w0 0.3, every 8 (nav values)|0.43=$E/pm_arm3_push2_online_navvalues.json#success" \
  "BlockPush 2|lr 3e-4, w0 0.3, every 8|0.43=$E/pm_arm3_push2_online_w03.json#success" \
  "BlockPush 2|lr 3e-4, w0 0.4, every 8|0.43=$E/pm_arm3_push2_online_papervalues.json#success" \
  "BlockPush 2|lr 3e-4, w0 0.5 (DSAC default), every 8|0.43=$E/pm_arm3_push2_online_w05.json#success" \
  "BlockPush 2|lr 3e-4, w0 0.4, every 1 (DSAC default)|0.43=$E/pm_arm3_push2_online_ue1.json#success" \
  "BlockPush 2|lr 3e-4, w0 0.4, every 8, A's prev obs pre-restart (hdt's default)|0.43=$E/pm_arm3_push2_online_prevobs.json#success" "$@"
