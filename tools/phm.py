#!/usr/bin/env python3
"""Read a PHM photon-map file and print its summary as JSON.

This is an independent reader for PHM version 1.x, written from
format-spec/phm-v1.md alone and using only Python's standard library.  It is
meant to be read: each step names the section of the specification it follows.

    python3 tools/phm.py FILE            # validate (§2-4) and print the §6 summary
    python3 tools/phm.py --check FILE    # ... and verify every column's CRC-32

On any violation it prints one line, ``phm.py: FILE: problem``, to standard
error and exits with status 1.

A PHM file is (§1):

    offset 0                 preamble, 32 bytes (§2)
    offset 32                metadata: UTF-8 JSON padded with whitespace (§3)
    offset 32 + metadata_len columns, each starting at a multiple of 64 (§4)
    offset file_len          end of file

Columns are a "structure of arrays": all photons' positions, then all photons'
fluxes, and so on.  Photon i's component k of a column is the element at index
``i * components + k``.
"""

import argparse
import array
import json
import struct
import sys
import zlib

# --- §2: the preamble -------------------------------------------------------

MAGIC = b"\x89PHM\r\n\x1a\n"
PREAMBLE = struct.Struct("<8sHHIQQ")  # magic, major, minor, metadata_crc32, metadata_len, file_len
assert PREAMBLE.size == 32

READ_MAJOR = 1  # the major version this reader understands (§8)
MAX_METADATA_LEN = 16 * 1024 * 1024  # 16 MiB

# --- §4: column element types -----------------------------------------------

# dtype -> (size in bytes, is float, signed).  The array type code is chosen
# below by item size, because C `int`/`long` widths vary between platforms.
DTYPES = {
    "u8": (1, False, False),
    "u16": (2, False, False),
    "u32": (4, False, False),
    "u64": (8, False, False),
    "i8": (1, False, True),
    "i16": (2, False, True),
    "i32": (4, False, True),
    "i64": (8, False, True),
    "f32": (4, True, True),
    "f64": (8, True, True),
}


def typecode(dtype):
    """The `array` type code whose items have the size and kind of `dtype`."""
    size, is_float, signed = DTYPES[dtype]
    if is_float:
        return "f" if size == 4 else "d"
    for code in ("bhilq" if signed else "BHILQ"):
        if array.array(code).itemsize == size:
            return code
    raise RuntimeError(f"this Python has no {size}-byte integer array type")


# §4.1: columns defined by version 1.0 and the (dtype, allowed component counts)
# a column with that name must have.
KNOWN_COLUMNS = {
    "position": ("f32", (3,)),
    "flux": ("f32", (3,)),
    "normal": ("f32", (3,)),
    "incident": ("f32", (3,)),
    "emitter": ("u16", (1,)),
    "params": ("f32", (2, 3, 4)),
    "path_length": ("f32", (1,)),
    "bounces": ("u8", (1,)),
    "emission_index": ("u64", (1,)),
    "surface": ("u32", (1,)),
    "basis_u": ("f32", (3,)),
    "basis_v": ("f32", (3,)),
    "lambda2": ("f32", (1,)),
    "r_param": ("f32", (1,)),
}
REQUIRED_COLUMNS = ("position", "flux")

U64_MAX = 2**64 - 1
U32_MAX = 2**32 - 1
JSON_WHITESPACE = b" \t\n\r"
INF = float("inf")


class PhmError(Exception):
    """A violation of the format; the message says what."""


# --- small JSON type checks -----------------------------------------------------


def is_int(v):
    # JSON integers parse to int; bool is a subclass of int in Python, exclude it.
    return isinstance(v, int) and not isinstance(v, bool)


def need_uint(obj, key, where, limit=U64_MAX):
    """obj[key] must be a JSON integer in 0..=limit (§3: integers fit in u64, CRCs in u32)."""
    if key not in obj:
        raise PhmError(f"{where}: missing key {key!r}")
    v = obj[key]
    if not is_int(v) or not 0 <= v <= limit:
        raise PhmError(f"{where}: {key!r} must be an integer in 0..={limit}, got {json.dumps(v)}")
    return v


def need(obj, key, types, what, where):
    if key not in obj:
        raise PhmError(f"{where}: missing key {key!r}")
    if not isinstance(obj[key], types):
        raise PhmError(f"{where}: {key!r} must be {what}")
    return obj[key]


def is_finite(x):
    """True for a finite float (NaN != NaN; x - x is NaN for ±Inf)."""
    return x - x == 0.0


def is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def reject_constant(name):
    # Python's json module accepts NaN and ±Infinity, which RFC 8259 does not.
    raise ValueError(f"{name} is not valid JSON")


def parse_float(text):
    # A number too large for f64 (1e999) would silently become Infinity.
    x = float(text)
    if not is_finite(x):
        raise ValueError(f"number {text} is out of range")
    return x


def unique_keys(pairs):
    # RFC 8259 leaves the meaning of duplicate names undefined; refuse them.
    obj = {}
    for key, value in pairs:
        if key in obj:
            raise ValueError(f"duplicate key {key!r}")
        obj[key] = value
    return obj


def need_xyz(v, what):
    """A JSON array of 3 numbers ([x, y, z] or [r, g, b])."""
    if not (isinstance(v, list) and len(v) == 3 and all(is_number(x) for x in v)):
        raise PhmError(f"{what} must be an array of 3 numbers")
    return v


# --- reading ---------------------------------------------------------------------


def read_preamble(f, actual_len):
    """§2: read and check the 32-byte preamble; returns (major, minor, crc, metadata_len, file_len)."""
    raw = f.read(32)
    if len(raw) < 32:
        raise PhmError(f"truncated: {len(raw)} bytes is shorter than the 32-byte preamble")
    magic, major, minor, meta_crc, meta_len, file_len = PREAMBLE.unpack(raw)
    if magic != MAGIC:
        raise PhmError("not a PHM file (bad magic number)")
    if major != READ_MAJOR:
        raise PhmError(
            f"PHM version {major}.{minor} is not supported: this reader reads major version {READ_MAJOR}"
        )
    # Checked before anything of that size is read or allocated.
    if meta_len > MAX_METADATA_LEN:
        raise PhmError(f"metadata_len {meta_len} exceeds the limit of {MAX_METADATA_LEN} bytes")
    if file_len > actual_len:
        raise PhmError(f"truncated: file_len says {file_len} bytes but the file has {actual_len}")
    if file_len < actual_len:
        raise PhmError(f"trailing data: file_len says {file_len} bytes but the file has {actual_len}")
    if 32 + meta_len > file_len:
        raise PhmError(f"metadata (32 + {meta_len} bytes) reaches past file_len {file_len}")
    return major, minor, meta_crc, meta_len, file_len


def parse_metadata(region):
    """§3: one JSON object in UTF-8, then only JSON whitespace to the end of the region."""
    try:
        text = region.decode("utf-8")
    except UnicodeDecodeError as e:
        raise PhmError(f"metadata is not UTF-8: {e}") from None
    # RFC 8259 allows whitespace before the value too; strip both ends.  Python's
    # str.strip() would also strip other Unicode spaces, so name the four bytes.
    body = text.strip(JSON_WHITESPACE.decode())
    try:
        meta = json.loads(body, parse_constant=reject_constant, parse_float=parse_float,
                          object_pairs_hook=unique_keys)
    except (ValueError, RecursionError) as e:
        raise PhmError(f"metadata is not valid JSON: {e}") from None
    if not isinstance(meta, dict):
        raise PhmError("metadata is not a JSON object")
    return meta


# §3.1: the number of parameter dimensions of each known parameterisation.
PARAM_DIMS = {"rect_uv": 2, "direction": 3, "rect_uv_spectral": 3, "direction_spectral": 4, "none": 0}


def check_metadata(meta):
    """§3: the required keys and their types, at every level; unknown keys are ignored.

    The spec states these as facts about the metadata rather than as rejection
    rules; this reader refuses metadata that contradicts them.
    """
    where = "metadata"
    n = need_uint(meta, "photon_count", where)
    need(meta, "columns", list, "an array", where)
    emitters = need(meta, "emitters", list, "an array", where)
    units = need(meta, "units", dict, "an object", where)
    bbox = need(meta, "bounding_box", (dict, type(None)), "an object or null", where)
    need(meta, "state", str, "a string", where)  # unknown states are accepted (§8)
    history = need(meta, "history", list, "an array", where)

    for key in ("length", "flux"):
        need(units, key, str, "a string", "units")

    # bounding_box: null if and only if there are no photons; otherwise min <= max.
    if (bbox is None) != (n == 0):
        raise PhmError("bounding_box must be null if and only if photon_count is 0")
    if bbox is not None:
        lo = need_xyz(need(bbox, "min", list, "an array", "bounding_box"), "bounding_box.min")
        hi = need_xyz(need(bbox, "max", list, "an array", "bounding_box"), "bounding_box.max")
        if any(a > b for a, b in zip(lo, hi)):
            raise PhmError("bounding_box: min is greater than max")

    # §3.1 emitter records.
    for i, e in enumerate(emitters):
        where = f"emitters[{i}]"
        if not isinstance(e, dict):
            raise PhmError(f"{where} is not an object")
        if need_uint(e, "id", where) != i:
            raise PhmError(f"{where} has id {e['id']}; an emitter's id must equal its index")
        need(e, "kind", str, "a string", where)  # unknown kinds are accepted (§8)
        param = need(e, "parameterisation", str, "a string", where)
        dims = need_uint(e, "param_dims", where)
        if param in PARAM_DIMS and dims != PARAM_DIMS[param]:
            raise PhmError(f"{where}: parameterisation {param!r} has {PARAM_DIMS[param]} dimensions, not {dims}")
        power = need(e, "power_w", (int, float), "a number", where)
        if isinstance(power, bool) or power < 0:
            raise PhmError(f"{where}: power_w must be a number >= 0")
        need_xyz(need(e, "colour", list, "an array", where), f"{where}.colour")
        if "param_measure" in e:
            measure = e["param_measure"]
            if not is_number(measure) or measure <= 0:
                raise PhmError(f"{where}: param_measure must be a number > 0")
        if "dimensions" in e:
            dl = e["dimensions"]
            if not isinstance(dl, list) or (dl and len(dl) != dims):
                raise PhmError(f"{where}: dimensions must be a list of param_dims entries")
            for d in dl:
                if not isinstance(d, dict):
                    raise PhmError(f"{where}: a dimension is not an object")
                need(d, "name", str, "a string", f"{where}.dimensions")
                need(d, "kind", str, "a string", f"{where}.dimensions")
                if "scale" in d and (not is_number(d["scale"]) or d["scale"] <= 0):
                    raise PhmError(f"{where}: a dimension's scale must be a number > 0")
                if "range" in d:
                    rg = d["range"]
                    if not (isinstance(rg, list) and len(rg) == 2 and all(is_number(x) for x in rg) and rg[0] <= rg[1]):
                        raise PhmError(f"{where}: a dimension's range must be [lo, hi] with lo <= hi")
        if "geometry" in e and not isinstance(e["geometry"], dict):
            raise PhmError(f"{where}: geometry must be an object")

    # §3.3 stage records.
    for i, r in enumerate(history):
        where = f"history[{i}]"
        if not isinstance(r, dict):
            raise PhmError(f"{where} is not an object")
        for key in ("stage", "version", "time"):
            need(r, key, str, "a string", where)
        if "parameters" not in r:
            raise PhmError(f"{where}: missing key 'parameters'")
    return n


def check_columns(meta, n, meta_len, file_len):
    """§4: validate the column table; returns the entries in table order."""
    columns = meta["columns"]
    names = set()
    for i, c in enumerate(columns):
        where = f"columns[{i}]"
        if not isinstance(c, dict):
            raise PhmError(f"{where} is not an object")
        name = need(c, "name", str, "a string", where)
        where = f"column {name!r}"
        if not 1 <= len(name.encode("utf-8")) <= 256:
            raise PhmError(f"{where}: name must be 1-256 bytes")
        if name in names:
            raise PhmError(f"{where}: duplicate column name")
        names.add(name)
        dtype = need(c, "dtype", str, "a string", where)
        if dtype not in DTYPES:
            raise PhmError(f"{where}: unknown dtype {dtype!r}")
        comps = need_uint(c, "components", where)
        offset = need_uint(c, "offset", where)
        length = need_uint(c, "length", where)
        need_uint(c, "crc32", where, U32_MAX)
        if not 1 <= comps <= 64:
            raise PhmError(f"{where}: {comps} components (must be 1-64)")
        expected = n * comps * DTYPES[dtype][0]  # Python ints do not overflow; compare with u64
        if expected > U64_MAX:
            raise PhmError(f"{where}: photon_count x components x size overflows u64")
        if length != expected:
            raise PhmError(f"{where}: length {length} != {n} photons x {comps} x {DTYPES[dtype][0]} bytes")
        if offset % 64:
            raise PhmError(f"{where}: offset {offset} is not a multiple of 64")
        if offset < 32 + meta_len:
            raise PhmError(f"{where}: offset {offset} lies inside the preamble or metadata")
        if offset + length > file_len:
            raise PhmError(f"{where}: bytes {offset}..{offset + length} reach past file_len {file_len}")
        if name in KNOWN_COLUMNS:  # §4.1
            want_dtype, want_comps = KNOWN_COLUMNS[name]
            if dtype != want_dtype or comps not in want_comps:
                want = " or ".join(str(k) for k in want_comps)
                raise PhmError(f"{where}: must be {want_dtype} x {want}, not {dtype} x {comps}")
    for name in REQUIRED_COLUMNS:
        if name not in names:
            raise PhmError(f"required column {name!r} is missing")
    if len(meta["emitters"]) > 1 and "emitter" not in names:
        raise PhmError("column 'emitter' is required when there is more than one emitter")
    if "params" in names:
        # §4.1: params has as many components as the largest param_dims.
        want = max((e["param_dims"] for e in meta["emitters"]), default=0)
        got = next(c["components"] for c in columns if c["name"] == "params")
        if got != want:
            raise PhmError(f"column 'params': {got} components, but the largest param_dims is {want}")
    # Overlap: sort the byte ranges [offset, offset + length) and compare neighbours.
    # Empty ranges (photon_count 0) hold no bytes and cannot overlap anything.
    spans = sorted((c["offset"], c["offset"] + c["length"], c["name"]) for c in columns if c["length"])
    for (_, end_a, a), (start_b, _, b) in zip(spans, spans[1:]):
        if start_b < end_a:
            raise PhmError(f"columns {a!r} and {b!r} overlap")
    return columns


def read_column(f, c, check_crc):
    """Read one column into a typed array (elements in file order, photon-major)."""
    size = DTYPES[c["dtype"]][0]
    values = array.array(typecode(c["dtype"]))
    f.seek(c["offset"])
    values.fromfile(f, c["length"] // size)  # all bytes are there: file_len was checked
    if check_crc and zlib.crc32(memoryview(values).cast("B")) != c["crc32"]:
        raise PhmError(f"column {c['name']!r}: CRC-32 mismatch (data corrupted)")
    if sys.byteorder == "big":  # the file is little-endian
        values.byteswap()
    return values


def finite_or_none(x):
    """JSON has no NaN or Infinity: a non-finite result is printed as null.

    (The spec does not say; this is what `photonkit inspect --json` prints.)
    """
    return x if is_finite(x) else None


def component_stats(values):
    """§6: min, max, mean over the finite values of one component, and counts of NaN and ±Inf.

    Every element is widened to f64 (Python floats are f64; f32 widening is exact).
    The mean is the f64 sum in photon order, starting from 0.0, divided by the count
    -- a plain loop, not sum() (compensated from Python 3.12) or math.fsum.
    """
    total = 0.0
    for x in values:
        total += x
    if is_finite(total):
        # A finite sum means every element is finite (NaN and Inf would propagate).
        if not values:
            return {"min": None, "max": None, "mean": None, "nan": 0, "inf": 0}
        return {"min": float(min(values)), "max": float(max(values)),
                "mean": total / len(values), "nan": 0, "inf": 0}
    # Some element is NaN or infinite: go again, keeping only the finite ones.
    total, count, nan, inf, lo, hi = 0.0, 0, 0, 0, None, None
    for x in values:
        if x != x:
            nan += 1
        elif x == INF or x == -INF:
            inf += 1
        else:
            total += x
            count += 1
            lo = x if lo is None or x < lo else lo
            hi = x if hi is None or x > hi else hi
    mean = finite_or_none(total / count) if count else None
    return {"min": lo, "max": hi, "mean": mean, "nan": nan, "inf": inf}


def summarise(path, check_crc=False):
    """Validate the file at `path` and return its §6 summary as a dict (keys in §6 order)."""
    with open(path, "rb") as f:
        f.seek(0, 2)
        actual_len = f.tell()
        f.seek(0)
        major, minor, meta_crc, meta_len, file_len = read_preamble(f, actual_len)

        region = f.read(meta_len)
        if zlib.crc32(region) != meta_crc:
            raise PhmError("metadata CRC-32 mismatch (metadata corrupted)")
        meta = parse_metadata(region)
        n = check_metadata(meta)
        columns = check_columns(meta, n, meta_len, file_len)

        total_flux = None
        column_summaries = []
        for c in columns:
            values = read_column(f, c, check_crc)
            comps = c["components"]
            stats = []
            for k in range(comps):
                # Component k of every photon: a strided slice of the column.
                component = values[k::comps] if comps > 1 else values
                stats.append(component_stats(component))
            if c["name"] == "flux":
                # §6 total_flux_w: every value (not only the finite ones) summed in photon order;
                # a NaN or Inf makes the channel's total null.
                total_flux = []
                for k in range(3):
                    s = 0.0
                    for x in values[k::3]:
                        s += x
                    total_flux.append(finite_or_none(s))
            column_summaries.append({
                "name": c["name"], "dtype": c["dtype"], "components": comps,
                "offset": c["offset"], "length": c["length"], "crc32": c["crc32"],
                "stats": stats,
            })

    # Keys in the order §6 gives.
    return {
        "file": path,
        "version": f"{major}.{minor}",
        "photon_count": n,
        "state": meta["state"],
        "units": meta["units"],
        "emitters": meta["emitters"],
        "bounding_box": meta["bounding_box"],
        "total_flux_w": total_flux,
        "columns": column_summaries,
        "history": meta["history"],
    }


def main(argv=None):
    ap = argparse.ArgumentParser(prog="phm.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("file", help="the PHM file")
    ap.add_argument("--check", action="store_true", help="also verify every column's CRC-32")
    args = ap.parse_args(argv)
    try:
        summary = summarise(args.file, check_crc=args.check)
    except PhmError as e:
        print(f"phm.py: {args.file}: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"phm.py: {args.file}: {e.strerror or e}", file=sys.stderr)
        return 1
    print(json.dumps(summary, indent=2, allow_nan=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
