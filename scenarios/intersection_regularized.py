# # Crack intersection, regularized pressure load (paper §3.1)
#
# The problem, its geometry and its measurements are described in
# `scenarios/intersection.py`; this script runs it with the
# aperture-based pressure factor (δ̄' = 0.1): the load enters the natural fracture at the junction and spreads as it opens.
#
#     mpirun -n 2 python scenarios/intersection_regularized.py [--quick] [--out DIR]
import runpy
import sys
from pathlib import Path

if __name__ == "__main__":
    intersection = runpy.run_path(str(Path(__file__).with_name("intersection.py")))
    intersection["main"](sys.argv[1:], regularized=True)
