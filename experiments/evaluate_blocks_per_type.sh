#!/usr/bin/env bash
# Building Blocks sub-tasks standalone, per block type, with the shipped policies (results/building_blocks.md):
# each of Search, Orient, Grasp and Insert in its own env, resets drawing only the given type (seqdex rollout
# --objects), 34 episodes x seeds 0, 1000, 2000 (102 per type and sub-task), deterministic. Default: the unseen
# types 6 7 8 (about 35 min on a core); give types to run others. Files already written are kept (rerun to resume).
# Outputs results/building_blocks/per_type/<task>_type<K>_seed<S>.json; the table:
#   python scripts/rollout_table.py results/building_blocks/per_type/*.json
#
#   bash experiments/evaluate_blocks_per_type.sh [TYPE ...]
set -euo pipefail
cd "$(dirname "$0")/.."
SEQDEX=${SEQDEX:-.venv/bin/seqdex}
OUT=results/building_blocks/per_type
TYPES=("$@")
[ ${#TYPES[@]} -eq 0 ] && TYPES=(6 7 8)
mkdir -p "$OUT"
for task in grasp orient insert search; do
    for type in "${TYPES[@]}"; do
        for seed in 0 1000 2000; do
            out="$OUT/${task}_type${type}_seed${seed}.json"
            [ -f "$out" ] && continue
            "$SEQDEX" rollout --task "$task" --checkpoint "checkpoints/building_blocks/stages/$task/best.pt" \
                --preset budget --objects "$type" --episodes 34 --seed "$seed" --out "$out"
        done
    done
done
