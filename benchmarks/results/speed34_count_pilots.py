"""Count pilot runs and remembered choices (and head-cost objects) over one matrix case."""
import sys, time
sys.path.insert(0, "benchmarks"); sys.path.insert(0, ".")
from siva_core._impl.simulate import substeps as S, pilot_memo as M
from siva_core._impl.diagnose import early_stop as E
n = {"pilot_runs": 0, "pilot_cpu_s": 0.0, "hits": 0, "heads_made": 0, "heads_asked": 0}
real_pilot, real_recall, real_hc = S._pilot, S.recall, E._HeadCosts.__init__
def pilot(*a, **k):
    t = time.process_time(); n["pilot_runs"] += 1
    try: return real_pilot(*a, **k)
    finally: n["pilot_cpu_s"] += time.process_time() - t
def recall(*a, **k):
    r = real_recall(*a, **k); n["hits"] += r is not None; return r
def hc(self, *a, **k):
    n["heads_made"] += 1; return real_hc(self, *a, **k)
real_head_costs = E.head_costs
def head_costs(*a, **k):
    n["heads_asked"] += 1; return real_head_costs(*a, **k)
S._pilot, S.recall, E._HeadCosts.__init__, E.head_costs = pilot, recall, hc, head_costs
import bench_diagnose
sys.argv = ["bench_diagnose.py", "--cases", sys.argv[1]]
try:
    bench_diagnose.main()
finally:
    print("COUNTS", n, flush=True)
