"""Schema-3 GPU tables made from schema-4 ones, for the tests that old assets keep reading and rendering."""
from __future__ import annotations

import numpy as np

from usdbtf.compress import packs


def schema3_tables(tables: np.ndarray, cbtf) -> np.ndarray:
    """Schema-3 tables of the same BTF from schema-4 ``tables``: the codes (2^23 + code,
    group-major) appended after the basis block's de-quantisation (the tables' last block), its
    offset 2^23: what ``package`` wrote before the basis page."""
    flat = np.asarray(tables, np.float32).reshape(-1, 4)
    basis_at, groups, k = int(flat[1, 1]), int(flat[0, 3]), int(flat[1, 0])
    at = basis_at + 1 + 2 * groups
    body = np.concatenate([flat[:at], packs.basis_codes_group_major(cbtf, k)])
    rows = -(-len(body) // packs.TABLE_WIDTH)
    out = np.zeros((rows * packs.TABLE_WIDTH, 4), np.float32)
    out[:len(body)] = body
    out[basis_at, 3] = packs.BASIS_CODE_OFFSET
    return out.reshape(rows, packs.TABLE_WIDTH, 4)
