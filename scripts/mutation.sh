#!/usr/bin/env bash
# Mutation testing of the core with mutmut 3. Not part of CI: the whole campaign takes
# an hour or more on 2 cores. What is mutated and which tests run are configured in pyproject.toml,
# [tool.mutmut]; this script runs mutmut in a scratch copy (runs/mutation/work, so the checkout never
# holds a mutants/ tree), then writes every mutant that was not killed, with its diff, to
# runs/mutation/survivors.txt and prints the score.
#
#   scripts/mutation.sh                                   # the whole campaign
#   MUTATION_ONLY="madp/models/action_stats.py" \
#   MUTATION_TESTS="tests/models/test_action_stats.py tests/models/test_madp.py" \
#   scripts/mutation.sh                                   # one module, a few test files
#
# Environment: MUTATION_ONLY / MUTATION_TESTS (space-separated) override only_mutate and the test
# selection; MUTATION_JOBS parallel mutants (default: the number of CPUs); MUTATION_OUT (default
# runs/mutation); MUTATION_RESUME=1 keeps the previous work/ (mutmut re-tests only what changed).
#
# Score = (killed + timeout) / (all mutants - skipped), as mutmut's badge computes it. Survivors
# still need a human: some are equivalent (the mutated code computes the same thing); list those,
# with the reason, in docs/reports/2026-12-02-mutation-testing.md.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PY="$ROOT/.venv/bin/python"
OUT=$(mkdir -p "${MUTATION_OUT:-runs/mutation}" && cd "${MUTATION_OUT:-runs/mutation}" && pwd)
WORK="$OUT/work"
JOBS=${MUTATION_JOBS:-$(nproc)}

# mutmut >= 3.8 (source_paths, only_mutate and pytest_add_cli_args_test_selection are read from pyproject)
if ! "$PY" -c 'import sys; from importlib.metadata import version; v = tuple(int(x) for x in version("mutmut").split(".")[:2]); sys.exit(not ((3, 8) <= v < (4, 0)))' 2>/dev/null; then
    echo "installing mutmut 3 into .venv"
    "$PY" -m pip install -q "mutmut>=3.8,<4"
fi
MUTMUT="$ROOT/.venv/bin/mutmut"

if [[ "${MUTATION_RESUME:-0}" != 1 ]]; then
    rm -rf "$WORK"
fi
mkdir -p "$WORK"
# The code, tests and configuration under test (cp -p keeps mtimes, so a resumed run sees what changed).
for p in madp tests pyproject.toml; do
    cp -rp "$ROOT/$p" "$WORK/"
done
find "$WORK" -name __pycache__ -prune -exec rm -rf {} +

if [[ "${MUTATION_RETEST:-0}" == 1 && -d "$WORK/mutants" ]]; then
    # mutmut keeps a verdict until the mutated function changes; new tests do not reset it
    "$PY" - "$WORK/mutants" <<'EOF'
import json, pathlib, sys
reset = 0
for meta in pathlib.Path(sys.argv[1]).rglob("*.meta"):
    m = json.loads(meta.read_text())
    codes = m["exit_code_by_key"]
    for key, code in codes.items():
        if code in (0, 33):  # survived, no tests
            codes[key] = None
            reset += 1
    meta.write_text(json.dumps(m, indent=4))
print(f"re-testing {reset} mutants that survived or had no tests")
EOF
fi

# Overrides for a partial run: rewrite [tool.mutmut] of the scratch copy only.
MUTATION_ONLY="${MUTATION_ONLY:-}" MUTATION_TESTS="${MUTATION_TESTS:-}" "$PY" - "$WORK/pyproject.toml" <<'EOF'
import json, os, re, sys, tomllib
path = sys.argv[1]
text = open(path).read()
cfg = tomllib.loads(text)["tool"]["mutmut"]
if os.environ["MUTATION_ONLY"]:
    cfg["only_mutate"] = os.environ["MUTATION_ONLY"].split()
if os.environ["MUTATION_TESTS"]:
    cfg["pytest_add_cli_args_test_selection"] = os.environ["MUTATION_TESTS"].split()
# drop the table (up to the next table header) and write it back in TOML (json's lists/strings are TOML too)
text = re.sub(r"(?ms)^\[tool\.mutmut\]\n.*?(?=^\[|\Z)", "", text)
body = "".join(f"{k} = {json.dumps(v)}\n" for k, v in cfg.items())
open(path, "w").write(text.rstrip("\n") + "\n\n[tool.mutmut]\n" + body)
print("mutating:", " ".join(cfg["only_mutate"]))
print("tests:   ", " ".join(cfg["pytest_add_cli_args_test_selection"]))
EOF

export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1

cd "$WORK"
start=$(date +%s)
# mutmut redraws one progress line with \r: the whole log goes to mutmut.log, its last lines to the terminal
"$MUTMUT" run --max-children "$JOBS" 2>&1 | tr '\r' '\n' > "$OUT/mutmut.log" || true
grep -v '^\s*$' "$OUT/mutmut.log" | tail -n 3
"$MUTMUT" export-cicd-stats >/dev/null
if [[ ! -f mutants/mutmut-cicd-stats.json ]]; then
    echo "mutmut produced no results; see $OUT/mutmut.log" >&2
    exit 1
fi

"$MUTMUT" results > "$OUT/not-killed.txt" || true
"$PY" - "$OUT" "$MUTMUT" "$(( $(date +%s) - start ))" <<'EOF'
import datetime, json, subprocess, sys
out, mutmut, seconds = sys.argv[1], sys.argv[2], int(sys.argv[3])
stats = json.load(open("mutants/mutmut-cicd-stats.json"))
rows = [line.strip().rsplit(": ", 1) for line in open(f"{out}/not-killed.txt") if ": " in line]
tested = stats["total"] - stats["skipped"]
score = 100.0 * (stats["killed"] + stats["timeout"]) / tested if tested else 0.0
head = (f"# mutmut {datetime.date.today()}: score {score:.1f}% = (killed {stats['killed']} + timeout "
        f"{stats['timeout']}) / {tested} mutants; survived {stats['survived']}, no tests {stats['no_tests']}, "
        f"suspicious {stats['suspicious']}, segfault {stats['segfault']}; {seconds} s\n")
with open(f"{out}/survivors.txt", "w") as f:
    f.write(head)
    for name, status in rows:
        if status in ("killed", "timeout"):
            continue
        diff = subprocess.run([mutmut, "show", name], capture_output=True, text=True).stdout
        f.write(f"\n## {name} ({status})\n{diff.strip()}\n")
json.dump({**stats, "score_percent": round(score, 2), "date": str(datetime.date.today()), "seconds": seconds},
          open(f"{out}/score.json", "w"), indent=1)
print(head.strip("# \n"))
print(f"survivors with diffs: {out}/survivors.txt")
EOF
