# # Crack intersection, unregularized pressure load (paper §3.1)
#
# The problem, its geometry and its measurements are described in
# `scenarios/intersection.py`; this script runs it with the
# load applied at once: f_p = 1 on the whole natural fracture the instant it is connected (the paper's first example).
#
#     mpirun -n 2 python scenarios/intersection_unregularized.py [--quick] [--out DIR]
import runpy
import sys
from pathlib import Path

if __name__ == "__main__":
    intersection = runpy.run_path(str(Path(__file__).with_name("intersection.py")))
    intersection["main"](sys.argv[1:], regularized=False)
