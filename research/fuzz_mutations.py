"""Seeded mutations of the inputs livecap reads, for research.fuzz_inputs: random byte-level
damage of any file, and structured mutations that know each format (MCAP records and their
length fields, BVH header values and rows, intrinsics.json fields, .npy headers in a body .npz,
Xbus and text-line serial bytes). Every function takes a ``random.Random`` and returns
(mutation name, new bytes); the same seed gives the same mutations.
"""

from __future__ import annotations

import io
import json
import random
import re
import struct
import zipfile

#: Integers that break length fields and counts: zero, one, sign bits, 2^31, 2^32, 2^40, 2^63.
INTERESTING = (0, 1, 0x7F, 0x80, 0xFF, 0x7FFF, 0x8000, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF,
               1 << 40, (1 << 63) - 1, 1 << 63, (1 << 64) - 1)
#: Values dropped into numeric text fields (BVH, JSON).
TEXT_NUMBERS = ("0", "-1", "-0", "1e308", "-1e308", "1e-300", "nan", "NaN", "inf", "-inf", "1e999",
                "100000000000000000000", "9223372036854775808", "0x10", "1,5", "", "abc", "\u0661")


def flip_bits(data: bytes, rng: random.Random, count: int | None = None) -> tuple[str, bytes]:
    count = count or rng.choice((1, 2, 8, 32))
    b = bytearray(data)
    for _ in range(count):
        i = rng.randrange(len(b))
        b[i] ^= 1 << rng.randrange(8)
    return f"flip {count} bits", bytes(b)


def put_integer(data: bytes, rng: random.Random, offset: int | None = None, width: int | None = None) -> tuple[str, bytes]:
    width = width or rng.choice((1, 2, 4, 8))
    value = rng.choice(INTERESTING) & ((1 << (8 * width)) - 1)
    offset = rng.randrange(max(1, len(data) - width)) if offset is None else offset
    b = bytearray(data)
    b[offset:offset + width] = value.to_bytes(width, "little")
    return f"int{8 * width} {value:#x} at {offset}", bytes(b)


def random_damage(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """One random byte-level damage: flips, an integer, truncation, a zeroed, repeated, removed or
    inserted range, garbage appended."""
    n = len(data)
    if n < 2:
        return "garbage", bytes(rng.randrange(256) for _ in range(64))
    kind = rng.randrange(8)
    start = rng.randrange(n)
    span = min(n - start, rng.choice((1, 7, 64, 512, 4096)))
    if kind == 0:
        return flip_bits(data, rng)
    if kind == 1:
        return put_integer(data, rng)
    if kind == 2:
        return f"truncate at {start}", data[:start]
    if kind == 3:
        return f"zero {span} bytes at {start}", data[:start] + bytes(span) + data[start + span:]
    if kind == 4:
        return f"repeat {span} bytes at {start}", data[:start + span] + data[start:start + span] + data[start + span:]
    if kind == 5:
        return f"remove {span} bytes at {start}", data[:start] + data[start + span:]
    if kind == 6:
        junk = bytes(rng.randrange(256) for _ in range(span))
        return f"insert {span} random bytes at {start}", data[:start] + junk + data[start:]
    return "append garbage", data + bytes(rng.randrange(256) for _ in range(rng.choice((1, 9, 300))))


# --- MCAP sessions ------------------------------------------------------------------------------

MCAP_MAGIC = b"\x89MCAP0\r\n"
_OPCODES = {0x01: "header", 0x02: "footer", 0x03: "schema", 0x04: "channel", 0x05: "message", 0x06: "chunk",
            0x07: "message index", 0x08: "chunk index", 0x09: "attachment", 0x0A: "attachment index",
            0x0B: "statistics", 0x0C: "metadata", 0x0D: "metadata index", 0x0E: "summary offset",
            0x0F: "data end"}


def mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, content length) of the top-level records of an MCAP file, as far as they
    parse (stops at the first length that runs past the end)."""
    out = []
    i = len(MCAP_MAGIC)
    while i + 9 <= len(data):
        op = data[i]
        (length,) = struct.unpack_from("<Q", data, i + 1)
        if i + 9 + length > len(data):
            break
        out.append((i, op, length))
        i += 9 + length
        if op == 0x02:
            break
    return out


def mutate_session(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """A structured mutation of one MCAP record (its opcode, its length, a length or size field
    inside a chunk or attachment, its content) or, one time in three, random damage."""
    records = mcap_records(data)
    if not records or rng.random() < 1 / 3:
        return random_damage(data, rng)
    offset, op, length = rng.choice(records)
    name = _OPCODES.get(op, f"opcode {op:#x}")
    b = bytearray(data)
    kind = rng.randrange(5)
    if kind == 0:
        b[offset] = rng.choice([o for o in range(256) if o != op])
        return f"{name} at {offset}: opcode {b[offset]:#x}", bytes(b)
    if kind == 1:
        value = rng.choice(INTERESTING)
        b[offset + 1:offset + 9] = value.to_bytes(8, "little")
        return f"{name} at {offset}: length {value:#x}", bytes(b)
    if kind == 2 and op == 0x06 and length > 40:
        # chunk: start(8) end(8) uncompressed size(8) uncompressed crc(4) compression(4+n) records(8+...)
        field = rng.choice((("uncompressed size", 9 + 16, 8), ("crc", 9 + 24, 4), ("compression length", 9 + 28, 4)))
        value = rng.choice(INTERESTING) & ((1 << (8 * field[2])) - 1)
        b[offset + field[1]:offset + field[1] + field[2]] = value.to_bytes(field[2], "little")
        return f"chunk at {offset}: {field[0]} {value:#x}", bytes(b)
    if kind == 3 and length > 0:
        return put_integer(data, rng, offset=offset + 9 + rng.randrange(length), width=rng.choice((1, 4, 8))
                           ) if length > 8 else flip_bits(data, rng, 1)
    start = offset + 9 + rng.randrange(max(1, length))
    return f"{name} at {offset}: cut inside", data[:start]


# --- BVH ----------------------------------------------------------------------------------------

def mutate_bvh(text: str, rng: random.Random) -> tuple[str, bytes]:
    """A structured BVH mutation (Frames / Frame Time values, CHANNELS counts, OFFSETs, motion
    values, lines removed, repeated or swapped, braces) or, one time in four, random damage."""
    if rng.random() < 0.25:
        return random_damage(text.encode(), rng)
    lines = text.splitlines()
    motion = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "MOTION"), len(lines) - 1)
    kind = rng.randrange(8)
    if kind == 0:
        key = rng.choice(("Frames:", "Frame Time:"))
        value = rng.choice(TEXT_NUMBERS + ("1000000", "100000000000", "2", "0.0000001"))
        out = [f"{key} {value}" if ln.strip().startswith(key) else ln for ln in lines]
        return f"{key} {value!r}", ("\n".join(out) + "\n").encode()
    if kind == 1:
        idx = [i for i, ln in enumerate(lines[:motion]) if ln.strip().startswith(("CHANNELS", "OFFSET"))]
        i = rng.choice(idx) if idx else 0
        tok = lines[i].split()
        if len(tok) > 1:
            tok[rng.randrange(1, len(tok))] = rng.choice(TEXT_NUMBERS + ("99999999999", "3", "Xrotation"))
        lines[i] = " ".join(tok)
        return f"header line {i + 1}: {lines[i][:40]!r}", ("\n".join(lines) + "\n").encode()
    if kind == 2 and motion + 3 < len(lines):
        i = rng.randrange(motion + 3, len(lines))
        tok = lines[i].split()
        if tok:
            tok[rng.randrange(len(tok))] = rng.choice(TEXT_NUMBERS)
        lines[i] = " ".join(tok)
        return f"motion row {i + 1}: a value replaced", ("\n".join(lines) + "\n").encode()
    i = rng.randrange(len(lines))
    if kind == 3:
        del lines[i]
        return f"line {i + 1} removed", ("\n".join(lines) + "\n").encode()
    if kind == 4:
        lines.insert(i, lines[i])
        return f"line {i + 1} repeated", ("\n".join(lines) + "\n").encode()
    if kind == 5:
        j = rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
        return f"lines {i + 1} and {j + 1} swapped", ("\n".join(lines) + "\n").encode()
    if kind == 6:
        brace = [k for k, ln in enumerate(lines[:motion]) if ln.strip() in ("{", "}")]
        k = rng.choice(brace) if brace else i
        lines[k] = rng.choice(("", "{", "}", "}}", "{ {"))
        return f"brace at line {k + 1} changed", ("\n".join(lines) + "\n").encode()
    return f"truncated after line {i + 1}", ("\n".join(lines[:i]) + "\n").encode()


# --- depth folders ------------------------------------------------------------------------------

_JSON_VALUES = (0, -1, 1e308, -1e308, 1e-300, float("nan"), float("inf"), 10**30, -(10**30), True, None, "abc", "",
                [], {}, [1, 2], [[1, 2], [3]], 64.5, 2**63)


def mutate_intrinsics(meta: dict, rng: random.Random, images: int) -> tuple[str, bytes]:
    """intrinsics.json with one field dropped, given a hostile value, or with hostile
    camera_to_world / timestamps_ns, or the whole file replaced by non-JSON."""
    m = dict(meta)
    kind = rng.randrange(6)
    if kind == 0 and m:
        key = rng.choice(sorted(m))
        del m[key]
        return f"intrinsics.json without {key}", json.dumps(m).encode()
    if kind == 1:
        key = rng.choice(sorted(m) + ["camera_to_world", "timestamps_ns"])
        m[key] = rng.choice(_JSON_VALUES)
        return f"intrinsics.json {key}={m[key]!r}", json.dumps(m).encode()
    if kind == 2:
        c2w = [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
        c2w[rng.randrange(4)][rng.randrange(4)] = rng.choice(_JSON_VALUES[:8])
        m["camera_to_world"] = c2w
        return f"camera_to_world {c2w}", json.dumps(m).encode()
    if kind == 3:
        stamps = [i * 33_333_333 for i in range(images)]
        j = rng.randrange(len(stamps))
        stamps[j] = rng.choice((-1, 0, 2**63, 10**18, 0.5, "1", None))
        m["timestamps_ns"] = stamps
        return f"timestamps_ns[{j}]={stamps[j]!r}", json.dumps(m).encode()
    if kind == 4:
        return random_damage(json.dumps(m).encode(), rng)
    return "intrinsics.json not an object", json.dumps(rng.choice(([1, 2], "x", 3, None))).encode()


def png_ihdr(width: int, height: int, bits: int, colour: int) -> bytes:
    """The first 33 bytes of a PNG (signature and IHDR with its CRC) declaring this image."""
    import zlib

    body = b"IHDR" + struct.pack(">IIBBBBB", width, height, bits, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + body + struct.pack(">I", zlib.crc32(body))


def mutate_png(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """A PNG whose IHDR declares another size or format (CRC kept valid, so decoders believe it),
    or random damage."""
    if rng.random() < 0.5 or len(data) < 33:
        return random_damage(data, rng)
    width, height = rng.choice(((1 << 20, 1 << 20), (0, 40), (64, 0), (23000, 23000), (65, 40), (64, 41)))
    bits, colour = rng.choice(((16, 0), (8, 0), (16, 2), (1, 0), (16, 4), (16, 6)))
    return f"PNG declaring {width}x{height}, {bits}-bit colour type {colour}", png_ihdr(width, height, bits, colour) + data[33:]


# --- body .npz ----------------------------------------------------------------------------------

_DTYPES = ("<f4", "<f8", "<i4", "|O", "<U1000000000", "|V8", "|S4", "<c8", "|b1")


def npy_header(descr: str, shape: tuple) -> bytes:
    buf = io.BytesIO()
    import numpy as np

    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue()


def mutate_npz(data: bytes, rng: random.Random) -> tuple[str, bytes]:
    """A body .npz with one member's .npy header declaring another shape or dtype (data kept),
    a member removed or duplicated under another name, or random damage of the zip."""
    if rng.random() < 0.3:
        return random_damage(data, rng)
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        members = {n: z.read(n) for n in z.namelist()}
    name = rng.choice(sorted(members))
    kind = rng.randrange(3)
    if kind == 0:
        shape = rng.choice(((1 << 40, 3), (0, 3), (7, 3), (1 << 31, 22), (3,), (), (1 << 62, 1 << 62), (-1, 3)))
        descr = rng.choice(_DTYPES[:3]) if rng.random() < 0.6 else rng.choice(_DTYPES)
        raw = members[name]
        head_len = raw.find(b"\n", 10) + 1 if raw.startswith(b"\x93NUMPY") else 0
        try:
            members[name] = npy_header(descr, shape) + raw[head_len:]
        except ValueError:  # numpy refuses to write some of these: write the text by hand
            text = repr({"descr": descr, "fortran_order": False, "shape": shape}).encode()
            members[name] = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text) + 1) + text + b"\n" + raw[head_len:]
        label = f"{name} declares {descr} {shape}"
    elif kind == 1:
        del members[name]
        label = f"{name} removed"
    else:
        members["x" + name] = members[name]
        members[name] = members[rng.choice(sorted(members))]
        label = f"{name} replaced by another member"
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=rng.choice((zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED))) as z:
        for n, raw in members.items():
            z.writestr(n, raw)
    return label, out.getvalue()


# --- serial bytes -------------------------------------------------------------------------------

def mutate_serial(reads: list[bytes], rng: random.Random) -> tuple[str, list[bytes]]:
    """Mutated serial reads: flipped bits across the stream, Xbus lengths and text-line fields
    replaced, random junk between reads, reads split, repeated or dropped."""
    out = list(reads)
    kind = rng.randrange(6)
    if kind == 0:
        for _ in range(rng.choice((1, 5, 50))):
            i = rng.randrange(len(out))
            if out[i]:
                out[i] = flip_bits(out[i], rng, 1)[1]
        return "bits flipped across the stream", out
    if kind == 1:
        for i in rng.sample(range(len(out)), min(len(out), 5)):
            out[i] = bytes(rng.randrange(256) for _ in range(rng.choice((1, 17, 600))))
        return "reads replaced by junk", out
    if kind == 2:
        # Xbus: preamble 0xFA, bus id, message id, length (0xFF = extended 16-bit length)
        for i in rng.sample(range(len(out)), min(len(out), 5)):
            b = bytearray(out[i])
            for m in re.finditer(b"\xfa\xff", bytes(b)):
                if m.start() + 3 < len(b):
                    b[m.start() + 3] = rng.choice((0, 0xFE, 0xFF))
                    if b[m.start() + 3] == 0xFF and m.start() + 5 < len(b):
                        b[m.start() + 4:m.start() + 6] = rng.choice((b"\xff\xff", b"\x00\x00", b"\x80\x00"))
            out[i] = bytes(b)
        return "Xbus length fields replaced", out
    if kind == 3:
        for i in rng.sample(range(len(out)), min(len(out), 5)):
            fields = out[i].split(b",")
            if len(fields) > 1:
                fields[rng.randrange(len(fields))] = rng.choice(TEXT_NUMBERS).encode()
            out[i] = b",".join(fields)
        return "text-line fields replaced", out
    if kind == 4:
        i = rng.randrange(len(out))
        cut = rng.randrange(len(out[i]) + 1)
        out[i:i + 1] = [out[i][:cut], out[i][cut:]]
        j = rng.randrange(len(out))
        out.insert(j, out[j])
        return "a read split, another repeated", out
    drop = sorted(rng.sample(range(len(out)), min(len(out) - 1, rng.choice((1, 10)))), reverse=True)
    for i in drop:
        del out[i]
    return f"{len(drop)} reads dropped", out
