#!/usr/bin/env bash
# Trains the shipped zoo (oodmon/zoo/<task>-<method>/) with the exact commands that produced it.
# Each training is resumable: run the script again after an interruption. Training folders go to
# runs/zoo/ (not committed); only the finished model.json and model.safetensors are copied.
#
#   bash scripts/train_zoo.sh                 # CartPole and Pendulum, every method (~40 min, 1 core)
#   bash scripts/train_zoo.sh pong-dropconnect  # one agent (Pong: hours; see the README)
set -euo pipefail
cd "$(dirname "$0")/.."
OODMON=${OODMON:-.venv/bin/oodmon}
agents=("$@")
if [ ${#agents[@]} -eq 0 ]; then
  agents=(cartpole-dropout cartpole-dropconnect cartpole-ensemble pendulum-dropout pendulum-dropconnect pendulum-ensemble)
fi
for agent in "${agents[@]}"; do
  task=${agent%%-*}
  method=${agent#*-}
  OODMON_TORCH_THREADS=1 "$OODMON" train --task "$task" --method "$method" --seed 0 --out "runs/zoo/$agent"
  mkdir -p "oodmon/zoo/$agent"
  cp "runs/zoo/$agent/model.json" "runs/zoo/$agent/model.safetensors" "oodmon/zoo/$agent/"
done
