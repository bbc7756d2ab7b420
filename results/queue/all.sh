#!/usr/bin/env bash
# Every queue, one after another, in the issues' order (one sweep at a time on the 2 cores): the driving Tables 1
# and 2 (issue 57), Table 5 with FCA's expert at 300k (issue 58), the on-policy check in the copycat cells and the
# remedies ranked (issue 59), then BC-full and softmax beside the 300k table (issue 58, if time allows); a queue
# that fails stops the ones after it. Each queue skips what has landed and
# resumes what was started, so rerunning this goes on where it stopped:
#   nohup results/queue/all.sh > /tmp/queues.log 2>&1 &
set -uo pipefail
Q=$(cd "$(dirname "$0")" && pwd)
# A sweep an earlier queue started and left running is waited for, then landed (`wait_for` in _lib.sh).
"$Q/toytown-tables.sh" && "$Q/table5-300k.sh" && "$Q/onpolicy-check.sh" && "$Q/remedies.sh" \
  && "$Q/table5-300k-more.sh"
