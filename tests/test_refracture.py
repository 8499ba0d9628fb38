"""Re-fracture behaviour at --quick size: closure after the load is removed, re-loading from
the perforations outward as the pumped fluid returns (docs/model.md, "A finite fluid volume")."""
import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import assert_dynamics_hold_penetration

ROOT = Path(__file__).resolve().parents[1]


VARIANTS = {"premeshed": ["--premeshed"], "growth": ["--growth"],
            "growth-no-microcracks": ["--growth", "--growth-nucleation-cap", "0"]}


@pytest.fixture(scope="module", params=list(VARIANTS))
def summary(request, tmp_path_factory):
    """The ways the cracks grow: freely from the perforation tips with remeshing and
    microcracks nucleating (the default, ``--growth``), the same without microcracks, and
    along pre-meshed radial paths (``--premeshed``)."""
    out = tmp_path_factory.mktemp(f"refracture_{request.param}")
    subprocess.run([sys.executable, str(ROOT / "scenarios" / "refracture.py"), "--quick", *VARIANTS[request.param],
                    "--out", str(out)], check=True, cwd=ROOT, capture_output=True, text=True)
    s = json.loads((out / "summary.json").read_text())
    s["variant"] = request.param
    if request.param != "premeshed":
        acc = s["accuracy"]
        # the main cracks grew at least as far as the pre-meshed paths reach (0.4 m beyond the
        # perforation tips) less one step (0.1 m): the fluid drives them there (no growth limit)
        assert acc["remeshes"] >= 3 and acc["extensions"] >= 4 * 3, acc
        assert acc["grown_length"] >= 4 * (0.4 - 0.1) - 1e-9, acc
        assert s["remeshing"]["remeshes"] == acc["remeshes"]
        # the default remesh is a local patch (--growth-remesh full: none)
        assert acc["local_remeshes"] >= 1, acc
    return s


def test_cracks_close_to_contact_without_energy_growth(summary):
    acc = summary["accuracy"]
    # most of the crack network has gone from separation to contact before the load returns
    assert acc["separated_fraction_before_reload"] < 0.6, acc
    # the opening never goes below the permitted penetration delta'_0 delta~, and the
    # dynamics keep it there: the opening clip never acted
    assert acc["min_opening"] >= acc["opening_floor"] * (1 + 1e-9), acc
    assert_dynamics_hold_penetration(summary)
    # no spurious energy: the budget error does not grow while the load is off
    assert acc["balance_error_growth_while_off"] < 1e-3 * acc["energy_scale"], acc


def test_reloading_spreads_from_the_perforations(summary):
    acc = summary["accuracy"]
    # the fluid flowed back with the removal: no facet kept its load, and the returning fluid
    # re-loads a part of the network (as far as the pumped volume reaches by the end)
    assert acc["loaded_when_reloading"] == 0, acc
    assert 10 <= acc["reloaded_facets"] <= acc["network_facets"], acc
    print(f"{summary['variant']}: re-load order Spearman {acc['reload_order_spearman']:.3f} (main cracks), "
          f"{acc['reload_order_spearman_network']:.3f} (network)")
    # (with an unlimited supply, --pump-rate inf, the free growth keeps the load on 15 facets
    # through the removal, and the first assertion fails)
    # Facets reach f_p > 0.5 in the order of their distance along the network from the
    # perforations: the returning fluid fills the network from them.  Not asserted for the free
    # growth at this size: 9 of its 13 re-loaded facets, within 0.12 m of the perforations,
    # re-load within 5 steps in an order set by each arm's opening (Spearman 0.73; 0.84 with an
    # unlimited supply, so the bound would not tell the two apart).  At full size the free
    # growth gives a median of 0.98 on the main cracks over seven mesh sizes
    # (docs/benchmarks.md, "The re-load order over seven mesh sizes, again").
    if summary["variant"] != "growth":
        assert acc["reload_order_spearman"] > 0.9, acc
        assert acc["reload_order_spearman_network"] > 0.9, acc


def test_microcracks_nucleate_grow_in_shear_and_stay_arrested_in_contact(summary):
    """The default re-fracture network (paper figs. 12a, 12g-i): microcracks nucleate where
    the bulk reaches the strength (the cap, 4), unloaded cracks grow in shear (slip beyond
    opening near the tip), and at the end some microcracks are closed (in contact on at least
    half their length), carry no load and have not grown since the load returned."""
    if summary["variant"] != "growth":
        pytest.skip("microcracks nucleate in the default free-growth run")
    acc = summary["accuracy"]
    assert acc["nucleations"] == acc["microcracks"] == 4, acc
    assert acc["unloaded_shear_extensions"] >= 1, acc
    assert acc["microcracks_arrested_closed"] >= 1, acc
    assert acc["microcracks_closed_at_end"] >= acc["microcracks_arrested_closed"], acc
