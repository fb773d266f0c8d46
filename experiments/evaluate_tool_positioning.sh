#!/usr/bin/env bash
# The Tool Positioning evaluation of results/tool_positioning.md, on the shipped checkpoints: the chain with and
# without the feasibility switcher, Policy-Seq, T-STAR and ours w/o temporal on the same budget, tool Grasp
# standalone, and the unseen tools.
# Every row: 34 episodes x the held-out seeds 100, 101, 102 (102 episodes per tool; no tuning, checkpoint choice
# or F fit used these seeds), the same episodes in every row. Two worker processes (the records do not depend on
# the split). About 60 minutes on two cores: a hammer row takes about 4 minutes, the unseen tools about 25 (slow
# contact-rich physics), tool Grasp standalone about 10. Outputs under results/tool_positioning/.
#
#   bash experiments/evaluate_tool_positioning.sh [--resume]
set -euo pipefail
cd "$(dirname "$0")/.."
SEQDEX=${SEQDEX:-.venv/bin/seqdex}
OUT=results/tool_positioning
COMMON=(--task tool_positioning --seed 100 --seeds 3 --workers 2 --skip-ablations "$@")

# Ours: the shipped chain with the switcher (at most 3 switches; it decides where a stage ends, the tool chain's
# trigger in evaluation/chain_settings.SWITCH_TRIGGER), the hammer.
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer --run-dir checkpoints/tool_positioning \
    --max-switches 3 --out "$OUT/eval_switcher" --label "ours (switcher, at most 3 switches)"
# Ours without the switcher: each stage runs its time budget in order.
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer --run-dir checkpoints/tool_positioning \
    --max-switches 0 --out "$OUT/eval_sequential" --label "ours without the switcher (sequential)"
# The switching ablation: at most 1 and 2 switches (0 and 3 are the rows above).
for switches in 1 2; do
    "$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer --run-dir checkpoints/tool_positioning \
        --max-switches "$switches" --out "$OUT/eval_switches_$switches" --label "ours (at most $switches switches)"
done
# Policy-Seq on the same budget: forward initialization only (its fine-tuning budget trains on the sub-task reward).
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer \
    --run-dir checkpoints/baselines/tool_positioning_policy_seq --max-switches 0 --out "$OUT/eval_policy_seq" \
    --label "Policy-Seq, same budget (sequential)"
# T-STAR on the same budget: tool Grasp fine-tuned with T-STAR's discriminator bonus at the hand-over.
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer \
    --run-dir checkpoints/baselines/tool_positioning_tstar --max-switches 0 --out "$OUT/eval_tstar" \
    --label "T-STAR, same budget (sequential)"
# Ours w/o temporal on the same budget (its F an MLP on the last observation), sequential and with the switcher.
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer \
    --run-dir checkpoints/baselines/tool_positioning_no_temporal --max-switches 0 \
    --out "$OUT/eval_no_temporal_sequential" --label "ours w/o temporal, same budget (sequential)"
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer \
    --run-dir checkpoints/baselines/tool_positioning_no_temporal --max-switches 3 \
    --out "$OUT/eval_no_temporal_switcher" --label "ours w/o temporal, same budget (switcher, at most 3 switches)"
# Tool Grasp standalone, the shipped (fine-tuned) policy, 3 x 100 episodes.
for seed in 3000 4000 5000; do  # Held out: tool Grasp was tuned on 0, 1000, 2000.
    "$SEQDEX" rollout --task tool_grasp --checkpoint checkpoints/tool_positioning/stages/tool_grasp/best.pt \
        --preset budget --episodes 100 --seed "$seed" --out "$OUT/tool_grasp_shipped_seed$seed.json"
done
# The unseen tools with the switcher.
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects spatula spoon --run-dir checkpoints/tool_positioning \
    --max-switches 3 --out "$OUT/eval_switcher_unseen" --label "ours (switcher, at most 3 switches)"
# The paper's switch timing (c^{i+1} every tick) on the same episodes: ours and ours w/o temporal.
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer --run-dir checkpoints/tool_positioning \
    --max-switches 3 --trigger next --out "$OUT/eval_switcher_next" \
    --label "ours (switcher, at most 3 switches, trigger next)"
"$SEQDEX" evaluate "${COMMON[@]}" --episodes 34 --objects hammer \
    --run-dir checkpoints/baselines/tool_positioning_no_temporal --max-switches 3 --trigger next \
    --out "$OUT/eval_no_temporal_switcher_next" \
    --label "ours w/o temporal, same budget (switcher, at most 3 switches, trigger next)"
# The switcher's timing on fresh seeds 200-202 (chosen on 100-102): where a stage ends (the shipped "decision"), the
# paper's every tick ("next"), and no switches.
for trigger in decision next; do
    "$SEQDEX" evaluate --task tool_positioning --seed 200 --seeds 3 --workers 2 --skip-ablations "$@" --episodes 34 \
        --objects hammer --run-dir checkpoints/tool_positioning --max-switches 3 --trigger "$trigger" \
        --out "$OUT/fresh_seeds_200/$trigger" --label "ours (switcher, trigger $trigger)"
done
"$SEQDEX" evaluate --task tool_positioning --seed 200 --seeds 3 --workers 2 --skip-ablations "$@" --episodes 34 \
    --objects hammer --run-dir checkpoints/tool_positioning --max-switches 0 --out "$OUT/fresh_seeds_200/sequential" \
    --label "ours (sequential)"
# The paired comparisons of results/tool_positioning.md (exact McNemar on the same 102 episodes): reads the records.
R=$OUT/eval
PYTHON=${PYTHON:-.venv/bin/python}
"$PYTHON" scripts/paired_table.py --row switcher=${R}_switcher --row switches_1=${R}_switches_1 \
    --row switches_2=${R}_switches_2 --row sequential=${R}_sequential --row policy_seq=${R}_policy_seq \
    --row tstar=${R}_tstar --row no_temporal=${R}_no_temporal_sequential \
    --row no_temporal_switcher=${R}_no_temporal_switcher --row next=${R}_switcher_next \
    --row no_temporal_next=${R}_no_temporal_switcher_next --pair switcher:sequential --pair switches_2:sequential \
    --pair switches_1:sequential --pair next:sequential --pair sequential:policy_seq --pair sequential:tstar \
    --pair tstar:policy_seq --pair sequential:no_temporal --pair no_temporal:policy_seq \
    --pair switcher:no_temporal_switcher --pair next:no_temporal_next --out "$OUT/paired.md"
