#!/bin/bash
# Submits a landing-evaluation sweep to Slurm: an array of SHARDS tasks (sweep.sbatch), then
# the merge (merge.sbatch), which runs only after every task has succeeded.
#   QOSRT=/shared/bin/qosrt QOSRT_SWEEP="--runs 20" deploy/slurm/submit.sh 8 [sbatch options…]
# Prints the two job ids. A failed task (or one killed with its node) is flown again with
# `scontrol requeue <array job>_<task>`; its file replaces the old one, and the merge can then
# be submitted again (`sbatch deploy/slurm/merge.sbatch`).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
shards=${1:?usage: submit.sh SHARDS [sbatch options…]}
shift
array=$(sbatch --parsable --array="1-$shards" "$@" "$here/sweep.sbatch")
array=${array%%;*}
merge=$(sbatch --parsable --dependency="afterok:$array" "$@" "$here/merge.sbatch")
merge=${merge%%;*}
echo "$array $merge"
