"""Property-based tests (hypothesis) of every reader of user files (issue 33): random bad
measurement tables, fit results and maps stores are either read cleanly (finite numbers)
or refused with an :class:`veil.errors.InputError` - what the command line prints as
"Error: ..." with exit status 2 (an OSError naming its file is status 2 too). Any other
exception is what the command line reports as a bug in veil, exit status 3, and fails here.

Derandomized (the same examples every run) and small, to stay within the suite's time.
"""

from __future__ import annotations

import json
import shutil
import string

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import veil
from support.maps import configurations, write_stack
from veil.cli import main
from veil.errors import InputError

SETTINGS = settings(derandomize=True, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


def clean_or_input_error(read, *args):
    """``read(*args)``: returns what it read, or None for an InputError (exit 2). Anything
    else raised is a bug (exit 3) and propagates."""
    try:
        return read(*args)
    except InputError:
        return None
    except OSError as exc:
        if exc.filename is None:  # the command line calls such an OSError a bug
            raise
        return None


# --------------------------------------------------------------------------------------
# measurement tables
# --------------------------------------------------------------------------------------
COLUMNS = ["psi", "rho", "theta_i", "phi_i", "theta_r", "phi_r", "value", "sigma", "file",
           "Value", "theta", " value", "sigma ", ""]
CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-90, 90).map(lambda x: f"{x:.6g}"),
    st.sampled_from(["", " ", "nan", "inf", "-inf", "1e400", "1e-320", "1,5", "0x10", "TRUE",
                     "1_000", "NaN", "--", "\"", "'3'", "1e-300", "2e302", "-0", "é", "\t"]),
    st.text(string.printable, max_size=6))


@st.composite
def csv_texts(draw):
    cols = draw(st.lists(st.sampled_from(COLUMNS), min_size=1, max_size=9))
    rows = draw(st.lists(st.lists(CELLS, min_size=len(cols), max_size=len(cols) + 1),
                         max_size=6))
    sep = draw(st.sampled_from([",", ",", ";", "\t"]))
    text = sep.join(cols) + "\n" + "".join(sep.join(r) + "\n" for r in rows)
    return draw(st.sampled_from(["", "\ufeff"])) + text


def _read_table(path):
    from veil.fitting.session_data import prepare

    table = veil.load_measurements(path)
    data = prepare(table)
    assert np.all(np.isfinite(data.y)) and all(np.all(np.isfinite(a)) for a in data.angles)
    if data.sigma is not None:
        assert np.all(np.isfinite(data.sigma)) and np.all(data.sigma > 0)
    return data


@settings(SETTINGS, max_examples=150)
@given(text=csv_texts())
def test_random_tables_are_read_or_refused(tmp_path, text):
    path = tmp_path / "table.csv"
    path.write_text(text, encoding="utf-8")
    clean_or_input_error(_read_table, path)


@settings(SETTINGS, max_examples=40)
@given(data=st.binary(max_size=200))
def test_random_bytes_as_a_table_are_refused(tmp_path, data):
    path = tmp_path / "table.csv"
    path.write_bytes(data)
    clean_or_input_error(_read_table, path)


@pytest.fixture(scope="module")
def good_table(tmp_path_factory):
    path = tmp_path_factory.mktemp("fuzz") / "ref.csv"
    veil.save_measurements(veil.simulate(veil.BRDF1, None, fine_step=10, coarse_step=20,
                                         seed=5), path)
    return path


@settings(SETTINGS, max_examples=60)
@given(row=st.integers(0, 30), column=st.sampled_from(COLUMNS[:8]), cell=CELLS)
def test_one_bad_cell_in_a_good_table_is_read_or_refused(tmp_path, good_table, row, column,
                                                         cell):
    lines = good_table.read_text().splitlines()
    head = lines[0].split(",")
    if column in head and row + 1 < len(lines):
        cells = lines[row + 1].split(",")
        cells[head.index(column)] = cell.replace(",", ";").replace("\n", " ")
        lines[row + 1] = ",".join(cells)
    path = tmp_path / "edited.csv"
    path.write_text("\n".join(lines) + "\n")
    clean_or_input_error(_read_table, path)


# --------------------------------------------------------------------------------------
# fit results
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def good_result(good_table):
    out = good_table.parent / "ref.json"
    result = CliRunner().invoke(main, ["fit", "reference", str(good_table), "-o", str(out)])
    assert result.exit_code == 0, result.output
    return json.loads(out.read_text())


JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10**30, 10**30),
              st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=8),
              st.sampled_from(["NaN", "Infinity", "torrance-sparrow", "joint", "medium"])),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=5), inner, max_size=3)),
    max_leaves=6)


def _paths(node, prefix=()):
    """Every key path of a JSON document."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for k, v in enumerate(node):
            yield from _paths(v, prefix + (k,))


def _read_result(path):
    from veil.fitting import load_result

    result = load_result(path)
    result.report()
    if hasattr(result, "as_model"):
        model = result.as_model()
        assert np.all(np.isfinite(model.to_vector()))
    return result


@settings(SETTINGS, max_examples=120)
@given(data=st.data())
def test_random_edits_of_a_result_are_read_or_refused(tmp_path, good_result, data):
    doc = json.loads(json.dumps(good_result))
    paths = [p for p in _paths(doc) if p]
    for _ in range(data.draw(st.integers(1, 3))):
        where = data.draw(st.sampled_from(paths))
        parent = doc
        try:
            for key in where[:-1]:
                parent = parent[key]
            if data.draw(st.booleans()) and isinstance(parent, dict):
                parent.pop(where[-1], None)
            else:
                parent[where[-1]] = data.draw(JSON_VALUES)
        except (KeyError, IndexError, TypeError):
            continue
    text = json.dumps(doc)
    if data.draw(st.integers(0, 9)) == 0:
        text = text[:data.draw(st.integers(0, len(text)))]
    path = tmp_path / "result.json"
    path.write_text(text)
    clean_or_input_error(_read_result, path)


# --------------------------------------------------------------------------------------
# maps stores
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def good_store(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzzstore")
    pm = np.repeat(veil.BRDF1.to_vector()[:, None, None], 4, 1).repeat(4, 2)
    manifest = write_stack(root / "photos", veil.BRDF1, veil.BTDF2, configurations(8), pm,
                           noise=0.0)
    out = root / "maps.zarr"
    result = CliRunner().invoke(main, [str(a) for a in [
        "fit", "maps", root / "photos", "--manifest", manifest, "--medium", "BTDF2", "--fix",
        "eta=1.5", "--grid", "n=0.3:3:6", "--tile", 8, "--accuracy", "fast", "-o", out]])
    assert result.exit_code == 0, result.output
    return out


def _read_store(store):
    from veil.maps.store import open_maps, summarize_maps

    maps = open_maps(store)
    summary = summarize_maps(store, maps)
    # what a clean read means: the numbers are the fitted ones, not fill values of lost
    # chunks (a converged pixel has more points than free parameters and fitted values)
    ok = maps["status"] == 0
    free = [k for k, n in enumerate(maps["info"]["params"]) if n in maps["info"]["free"]]
    assert np.all(maps["n_points"][ok] > len(free))
    assert np.all(maps["params"][free][:, ok] != 0) and np.all(maps["stderr"][free][:, ok] > 0)
    json.dumps(summary, allow_nan=False)  # finite numbers only
    return summary


@settings(SETTINGS, max_examples=50)
@given(data=st.data())
def test_random_damage_to_a_store_is_read_or_refused(tmp_path, good_store, data):
    store = tmp_path / "store.zarr"
    if store.exists():
        shutil.rmtree(store)
    shutil.copytree(good_store, store)
    files = sorted(p for p in store.rglob("*") if p.is_file())
    for _ in range(data.draw(st.integers(1, 2))):
        victim = data.draw(st.sampled_from(files))
        if not victim.exists():
            continue
        how = data.draw(st.sampled_from(["delete", "truncate", "garbage", "json"]))
        if how == "delete":
            victim.unlink()
        elif how == "truncate":
            raw = victim.read_bytes()
            victim.write_bytes(raw[:data.draw(st.integers(0, max(len(raw) - 1, 0)))])
        elif how == "garbage":
            victim.write_bytes(data.draw(st.binary(max_size=64)))
        elif victim.name == "zarr.json":  # valid JSON, one attribute changed
            try:
                doc = json.loads(victim.read_bytes())
            except ValueError:  # damaged by the first edit of this example
                continue
            if not isinstance(doc, dict):
                continue
            node = doc.get("attributes", {}).get("veil_maps", doc)
            key = data.draw(st.sampled_from(sorted(node) or ["x"]))
            node[key] = data.draw(JSON_VALUES)
            victim.write_text(json.dumps(doc))
    clean_or_input_error(_read_store, store)


@settings(SETTINGS, max_examples=80)
@given(edits=st.lists(st.tuples(st.sampled_from(
    ["params", "free", "fixed_values", "shape", "tile", "outside_mask", "photos", "model",
     "medium", "units", "geometry", "weighted", "noise_of", "format", "status_codes",
     "noise"]),
    st.one_of(st.just("delete"), JSON_VALUES)), min_size=1, max_size=2))
def test_random_store_attributes_are_read_or_refused(tmp_path, good_store, edits):
    """The store's own attributes (root zarr.json, ``veil_maps``) edited: every reader,
    the figure's panels included, reads them cleanly or says the store is damaged."""
    from veil.maps.show import _panels
    from veil.maps.store import open_maps

    store = tmp_path / "store.zarr"
    if store.exists():
        shutil.rmtree(store)
    shutil.copytree(good_store, store)
    doc = json.loads((store / "zarr.json").read_text())
    info = doc["attributes"]["veil_maps"]
    for key, value in edits:
        if value == "delete":
            info.pop(key, None)
        else:
            info[key] = value
    (store / "zarr.json").write_text(json.dumps(doc))
    clean_or_input_error(_read_store, store)
    clean_or_input_error(lambda s: _panels(open_maps(s)), store)
