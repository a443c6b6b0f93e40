"""candeck's EDS reader against python-canopen's on the corpus of real files.

Every file of tests/data/eds-corpus is read by `candeck eds check --json
--dictionary` and by python-canopen's `import_od`. Where python-canopen reads
a file, each entry it keeps is compared: object kind (variable, array,
record), data type, access type, PDO mapping and default value.

Where the two readers differ by a documented rule of candeck's tolerant
reader (docs/eds.md, "Reading EDS files"), the entry is compared by that rule:
python-canopen keeps what candeck reads as something else (an empty access
type, a data type that is no basic type, a default with a C suffix or a
negative unsigned number), so those are compared as candeck's rule reads them
and counted. Python-canopen reads text as UTF-8 only; it is given the text
decoded as candeck decodes it (UTF-8, else Windows-1252, else Latin-1), so
that the comparison is of the dictionaries, not of the decoders.
"""

import base64
import io
import json
import math
import os
import subprocess

import canopen
import pytest

from conftest import BIN

CORPUS = os.path.join(os.path.dirname(__file__), "..", "data", "eds-corpus")
FILES = sorted(f for f in os.listdir(CORPUS) if f.lower().endswith((".eds", ".dcf")))

# CiA 301 basic types python-canopen and candeck both know.
BASIC = set(range(0x01, 0x1C)) - {0x0E, 0x17}  # not 0x0E, 0x17 (no types)
ACCESS = {"ro", "wo", "rw", "rwr", "rww", "const"}
DOMAIN = 0x0F
TEXT = {0x09, 0x0B}  # VISIBLE_STRING, UNICODE_STRING
BYTES = {0x0A, 0x0F}  # OCTET_STRING, DOMAIN
REAL = {0x08, 0x11}
BITS = {0x01: 1, 0x02: 8, 0x03: 16, 0x04: 32, 0x05: 8, 0x06: 16, 0x07: 32, 0x10: 24,
        0x12: 40, 0x13: 48, 0x14: 56, 0x15: 64, 0x16: 24, 0x18: 40, 0x19: 48,
        0x1A: 56, 0x1B: 64}


def decoded(path):
    data = open(path, "rb").read()
    for encoding in ("utf-8-sig", "cp1252", "latin-1"):
        try:
            return data.decode(encoding)
        except UnicodeDecodeError:
            continue
    raise AssertionError("latin-1 decodes anything")


@pytest.fixture(scope="module")
def candeck_dictionaries():
    paths = [os.path.join(CORPUS, f) for f in FILES]
    run = subprocess.run([BIN, "eds", "check", "--json", "--dictionary", *paths],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return {os.path.basename(entry["file"]): entry for entry in json.loads(run.stdout)}


def python_variables(od):
    """(index, sub) -> (kind of the object, ODVariable) for every entry kept."""
    out = {}
    for index, obj in od.items():
        if not isinstance(index, int):
            continue
        if isinstance(obj, canopen.objectdictionary.ODVariable):
            # python-canopen lists [DummyUsage] as variables 0x0001-0x0007;
            # candeck keeps that list apart from the dictionary.
            if index <= 0x0007 and obj.name.startswith("Dummy"):
                continue
            out[(index, 0)] = ("variable", obj)
        else:
            kind = "array" if isinstance(obj, canopen.objectdictionary.ODArray) else "record"
            for sub, var in obj.subindices.items():
                out[(index, sub)] = (kind, var)
    return out


def same_default(data_type, ours, theirs):
    """Our default (REST JSON form) against python-canopen's, by type."""
    if data_type in TEXT:
        return ours == theirs.strip('"')
    if data_type in BYTES:
        return base64.b64decode(ours) == theirs
    if data_type in REAL:
        return float(ours) == theirs or (math.isnan(float(ours)) and math.isnan(theirs))
    if data_type == 0x01:
        return bool(ours) == bool(theirs)
    # Integers: python-canopen keeps hex beyond a signed maximum and negative
    # unsigned numbers as written; both are the same bits.
    bits = BITS.get(data_type, 64)
    return int(ours) % (1 << bits) == int(theirs) % (1 << bits)


def test_the_corpus_is_large_and_candeck_reads_every_file(candeck_dictionaries):
    assert len(FILES) >= 60
    unusable = [f for f, entry in candeck_dictionaries.items() if not entry["usable"]]
    assert not unusable


def test_dictionaries_agree_with_python_canopen(candeck_dictionaries):
    compared = {"files": 0, "entries": 0, "by_rule": 0}
    python_failed = []
    mismatches = []
    for name in FILES:
        ours = candeck_dictionaries[name]
        source = io.StringIO(decoded(os.path.join(CORPUS, name)))
        source.name = name
        try:
            od = canopen.import_od(source)
        except Exception as error:  # python-canopen refuses the file
            python_failed.append(f"{name}: {type(error).__name__}: {error}")
            continue
        compared["files"] += 1
        entries = {}
        kinds = {}
        for obj in ours["dictionary"]:
            kinds[obj["index"]] = obj["object_type"]
            for sub in obj["subs"]:
                entries[(obj["index"], sub["sub_index"])] = sub
        for (index, sub), (kind, var) in python_variables(od).items():
            where = f"{name} 0x{index:04X}/{sub}"
            entry = entries.get((index, sub))
            if entry is None:
                mismatches.append(f"{where}: python-canopen has it, candeck not")
                continue
            compared["entries"] += 1
            object_type = kinds[index]
            our_kind = {0x7: "variable", 0x2: "variable", 0x8: "array", 0x9: "record"}[object_type]
            if our_kind != kind:
                mismatches.append(f"{where}: object {our_kind} vs {kind}")
            data_type = var.data_type
            if data_type in BASIC:
                if entry["data_type"] != data_type:
                    mismatches.append(f"{where}: type 0x{entry['data_type']:X} vs 0x{data_type:X}")
            else:
                # Rule: a type that is no basic type is DOMAIN.
                compared["by_rule"] += 1
                if entry["data_type"] != DOMAIN:
                    mismatches.append(f"{where}: type 0x{entry['data_type']:X} for 0x{data_type:X}")
                continue
            access = var.access_type
            if access in ACCESS:
                # python-canopen names compact sub 0 itself, with its own access.
                if entry["access"] != access and not (sub == 0 and var.name == "Number of entries"):
                    mismatches.append(f"{where}: access {entry['access']} vs {access}")
            else:
                # Rule: an empty or unknown access type is rw.
                compared["by_rule"] += 1
                if entry["access"] != "rw":
                    mismatches.append(f"{where}: access {entry['access']} for {access!r}")
            if entry["pdo_mappable"] != bool(var.pdo_mappable):
                mismatches.append(f"{where}: PDO mapping {entry['pdo_mappable']} vs {var.pdo_mappable}")
            # An empty DefaultValue= is no default for candeck, an empty
            # value for python-canopen.
            if var.default in (b"", ""):
                var.default = None
            if var.default is not None:
                if entry["default_value"] is None:
                    # Rule: a DOMAIN default that is no hex bytes is
                    # dropped; python-canopen would have refused it too.
                    mismatches.append(f"{where}: no default vs {var.default!r}")
                elif not same_default(data_type, entry["default_value"], var.default):
                    mismatches.append(
                        f"{where}: default {entry['default_value']!r} vs {var.default!r}")
            elif getattr(var, "default_raw", None) not in (None, "") and entry["default_value"] is not None \
                    and "$NODEID" not in var.default_raw.upper():
                # python-canopen could not read the default; candeck read it
                # by a rule (a C suffix, a negative unsigned number).
                compared["by_rule"] += 1
    print(f"compared: {compared}; python-canopen refused {len(python_failed)} files")
    for failure in python_failed:
        print("  python-canopen:", failure)
    # python-canopen 2.4.1 reads 52 of the 62 files; it refuses Lely's DCFs
    # without Dummy000N keys, CANopenNode's files whose [Comments] count more
    # lines than they have, and an empty number.
    assert compared["files"] >= 50, python_failed
    assert not mismatches, "\n".join(mismatches[:50]) + f"\n({len(mismatches)} in all)"
