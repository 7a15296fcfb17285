"""Hypothesis strategies for malformed trained-classifier files, shared by the loader's fuzz
test (tests/mux_classifier) and the classifier node's (tests/mux_classifier/test_inference_graph.py).

`mutated_artifacts(original)` draws the bytes of a file derived from a valid artifact: the
whole file's bytes mutated, or its zip members replaced, mutated, dropped or added, or one
header field given another JSON value -- rewritten into a zip with correct CRCs, so that the
loader's own checks are reached, not only the zip's.
"""
from __future__ import annotations

import io
import json
import zipfile

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp


def zip_members(data: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def zip_bytes(members: dict[str, bytes], compression=zipfile.ZIP_STORED) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, 'w', compression) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return out.getvalue()


def npy_bytes(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.save(out, array, allow_pickle=False)
    return out.getvalue()


def mutate_bytes(draw, data: bytes) -> bytes:
    """1-4 byte-level edits: flip a bit, drop/insert/overwrite bytes, truncate."""
    data = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(['flip', 'drop', 'insert', 'overwrite', 'truncate']))
        at = draw(st.integers(0, max(0, len(data) - 1)))
        if kind == 'flip' and data:
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif kind == 'drop':
            del data[at:at + draw(st.integers(1, 16))]
        elif kind == 'insert':
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == 'overwrite':
            chunk = draw(st.binary(min_size=1, max_size=16))
            data[at:at + len(chunk)] = chunk
        elif kind == 'truncate':
            del data[at:]
    return bytes(data)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=8)

small_arrays = hnp.arrays(hnp.scalar_dtypes(), hnp.array_shapes(min_dims=0, max_dims=3, max_side=4))


def mutated_artifacts(original: bytes) -> st.SearchStrategy[bytes]:
    """Files derived from the artifact file ``original`` (its bytes), each malformed in one way."""
    original_members = zip_members(original)
    original_header = json.loads(np.load(io.BytesIO(original_members['header.npy'])).tobytes().decode())

    @st.composite
    def mutated(draw) -> bytes:  # a closure: the strategy's repr does not hold the file
        kind = draw(st.sampled_from(['file_bytes', 'member_bytes', 'member_garbage',
                                     'member_array', 'member_dropped', 'member_added',
                                     'header_field']))
        if kind == 'file_bytes':
            return mutate_bytes(draw, original)
        members = dict(original_members)
        name = draw(st.sampled_from(sorted(members)))
        if kind == 'member_bytes':
            members[name] = mutate_bytes(draw, members[name])
        elif kind == 'member_garbage':
            members[name] = draw(st.binary(max_size=64))
        elif kind == 'member_array':
            members[name] = npy_bytes(draw(small_arrays))
        elif kind == 'member_dropped':
            del members[name]
        elif kind == 'member_added':
            added = draw(st.sampled_from(['coef_1.npy', 'site_patterns.npy', 'x.npy', 'header']))
            members[added] = draw(st.binary(max_size=64) | small_arrays.map(npy_bytes))
        else:
            header = json.loads(json.dumps(original_header))  # a deep copy
            target = header
            key = draw(st.sampled_from(sorted(header)))
            if isinstance(header[key], dict) and header[key] and draw(st.booleans()):
                target = header[key]  # one field of the noise setting, the HOG configuration ...
                key = draw(st.sampled_from(sorted(target)))
            if draw(st.booleans()):
                target[key] = draw(json_values)
            else:
                del target[key]
            members['header.npy'] = npy_bytes(np.frombuffer(json.dumps(header).encode(), np.uint8))
        compression = draw(st.sampled_from([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED]))
        return zip_bytes(members, compression)

    return mutated()
