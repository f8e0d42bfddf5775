#!/usr/bin/env bash
# Regenerate docs/results.md and docs/img/bench_*.png from a full benchmark on the shared sequences:
# the manifold tracker (the default and the paper's likelihood) and IPCA with 3 seeds, CSRT, KCF and MIL once, every sequence under ROOT,
# every loss replayed under each fix (--counterfactual: the report's losses by verdict and what fixing each would gain).
# Resumable: run it again after an interruption and finished runs are kept (runs kept from a bench without
# --counterfactual have no replays: delete them, or add --force once).
#
#   bash scripts/make_results.sh [ROOT] [RUNS_DIR]
#
# ROOT defaults to ../shared/sequences, RUNS_DIR to runs/bench (outside git: runs/ is ignored); the ablation
# goes to RUNS_DIR-ablation.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=${1:-../shared/sequences}
RUNS=${2:-runs/bench}
covviz bench "$ROOT" --trackers manifold,manifold-paper,ipca,csrt,kcf,mil --seeds 3 --jobs 2 --counterfactual --out "$RUNS" --no-report
# The default likelihood's ablation: each change alone and together, seeds 0-5, and its cost (appended to the report).
python benchmarks/ablation.py "$ROOT" --out "$RUNS-ablation" --seeds 6 --jobs 2 --md "$RUNS-ablation/ablation.md"
covviz report "$RUNS" --out docs/results.md --append "$RUNS-ablation/ablation.md"
# The label-free drift detector (issue 21): the shipped models refitted on seeds 0-5, leave-one-sequence-out on
# seeds 0-5, and the shipped models checked on seeds 6-8 (fitted and chosen without them), appended as its own section.
covviz bench "$ROOT" --trackers manifold,manifold-paper,ipca,csrt,kcf,mil --seeds 9 --jobs 2 --out "$RUNS-drift" --no-report
covviz calibrate "$RUNS-drift" --seeds 0-5 --all-families covviz/diagnosis/models
python scripts/drift_eval.py "$RUNS-drift" --loso-seeds 0-5 --jobs 2 --write docs/results.md
echo "wrote docs/results.md and docs/img/bench_*.png from $RUNS"
