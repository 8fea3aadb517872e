#!/usr/bin/env bash
# The worked examples' rows (README "Worked examples: Gymnasium and MuJoCo"): 100 initial states per row, drawn
# from each plant's box with seed 42 (results/sweep_lib.sh x0_box), condensed into results/plants/<row>.csv:
#   gym_pendulum_{lmpc,lqr,model-lqr}            Gymnasium Pendulum-v1, θ ∈ [-0.6, 0.6], θ̇ ∈ [-1.5, 1.5]
#   gym_inverted_pendulum_{lmpc,lqr,model-lqr}   MuJoCo InvertedPendulum-v5, cart ∈ [-0.5, 0.5] m,
#                                                angle ∈ [-0.6, 0.6] rad, velocities 0
# lmpc: the preset (+experiment=gym_pendulum / gym_inverted_pendulum: learned only from the environment's own
# excited runs); lqr: the LQR on the environment's numerical linearisation (controller=lqr, no formula exists);
# model-lqr: the identified model's own LQR (controller=model_lqr).  No NMPC oracle: it needs a formula.
# Whether an LQR failure could be saved at all: results/plants_ocp.py wrote results/plants/<system>_ocp.csv for
# the same 100 x0.  The table: kexp-results plants results/plants/*.csv
#
#   results/plants.sh ROW [ROW ...]     # e.g. gym_pendulum_lmpc
#   results/plants.sh --list            # every row
#   results/plants.sh --overrides ROW   # the row's kexp overrides, one per line
set -euo pipefail
cd "$(dirname "$0")/.."
source results/sweep_lib.sh

box() {  # SYSTEM -> "LOW HIGH" of its initial states
    case $1 in
        gym_pendulum) echo "-0.6,-1.5 0.6,1.5" ;;
        gym_inverted_pendulum) echo "-0.5,-0.6,0,0 0.5,0.6,0,0" ;;
        *) echo "unknown system $1" >&2; return 2 ;;
    esac
}

overrides() {  # ROW -> the kexp overrides of that row
    local system=${1%_*} ctrl=${1##*_}
    box "$system" > /dev/null || return 2
    echo "+experiment=$system"
    case $ctrl in
        lmpc) ;;
        lqr) echo controller=lqr ;;
        model-lqr) echo controller=model_lqr ;;
        *) echo "unknown controller in row $1 (lmpc, lqr, model-lqr)" >&2; return 2 ;;
    esac
}

if [ "${1:-}" = "--overrides" ]; then
    [ $# = 2 ] || { echo "usage: $0 --overrides ROW" >&2; exit 2; }
    overrides "$2"; exit
fi
ROWS=()
for s in gym_pendulum gym_inverted_pendulum; do for c in lmpc lqr model-lqr; do ROWS+=("${s}_$c"); done; done
if [ "${1:-}" = "--list" ]; then printf '%s\n' "${ROWS[@]}"; exit 0; fi
[ $# -gt 0 ] || { echo "usage: $0 ROW [ROW ...] | --list | --overrides ROW" >&2; exit 2; }
for row in "$@"; do
    mapfile -t ov < <(overrides "$row")
    [ ${#ov[@]} -gt 0 ] || exit 2
    read -r lo hi < <(box "${row%_*}")
    sweep_row "$row" "sweeps/plants/$row" results/plants "$(x0_box "$lo" "$hi")" "${ov[@]}"
done
