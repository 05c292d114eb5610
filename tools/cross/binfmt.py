"""Read what a compiled Python extension module links to and exports: PE32+ (Windows), Mach-O
(macOS, 64-bit) and ELF (Linux, 64-bit), little-endian only (every platform Blender ships for).

Owns: the header parsers tests/test_platforms.py uses to check the cross-built and native
products (file format, CPU, exported PyInit_* functions, imported libraries and symbols). Only
the tables needed for that are read: PE export/import directories, Mach-O load commands and
LC_SYMTAB, ELF .dynsym/.dynamic. Symbol names come back as C names (Mach-O's leading underscore
removed).

    python tools/cross/binfmt.py FILE...    # prints the summary of each file
"""
from __future__ import annotations

import json
import struct
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

DYNAMIC_LOOKUP = "(dynamic lookup)"  # Mach-O: bound to whatever image defines it (the interpreter)
ANY_LIBRARY = "(any library)"        # ELF: undefined symbols are not tied to a library


@dataclass
class Binary:
    format: str                      # "PE32+", "Mach-O", "ELF"
    arch: str                        # "x86-64", "arm64"
    kind: str                        # "dll", "dylib", "bundle", "shared object", ...
    libraries: list[str]             # DLLs / dylibs / DT_NEEDED, in file order
    imports: dict[str, list[str]]    # library (or DYNAMIC_LOOKUP / ANY_LIBRARY) -> symbols
    exports: list[str]
    min_os: str | None = None        # Mach-O: LC_BUILD_VERSION / LC_VERSION_MIN_MACOSX
    signed: bool = False             # Mach-O: has LC_CODE_SIGNATURE (arm64 macOS runs no unsigned code)
    notes: list[str] = field(default_factory=list)

    def imported(self) -> set[str]:
        return {s for names in self.imports.values() for s in names}


class FormatError(ValueError):
    pass


def read(path) -> Binary:
    data = Path(path).read_bytes()
    if data[:2] == b"MZ":
        return _pe(data)
    if data[:4] == b"\xcf\xfa\xed\xfe":
        return _macho(data)
    if data[:4] == b"\x7fELF":
        return _elf(data)
    raise FormatError(f"{path}: neither PE, 64-bit little-endian Mach-O nor ELF (magic {data[:4]!r})")


def _cstr(data: bytes, offset: int) -> str:
    end = data.index(b"\0", offset)
    return data[offset:end].decode("ascii", "replace")


# ------------------------------------------------------------------------------------------------
# PE / COFF


PE_MACHINES = {0x8664: "x86-64", 0xAA64: "arm64", 0x14C: "x86"}


def _pe(data: bytes) -> Binary:
    (lfanew,) = struct.unpack_from("<I", data, 0x3C)
    if data[lfanew:lfanew + 4] != b"PE\0\0":
        raise FormatError("no PE signature")
    coff = lfanew + 4
    machine, nsections, _, _, _, opt_size, characteristics = struct.unpack_from("<HHIIIHH", data, coff)
    opt = coff + 20
    (magic,) = struct.unpack_from("<H", data, opt)
    if magic != 0x20B:
        raise FormatError(f"optional header magic {magic:#x} is not PE32+")
    (ndirs,) = struct.unpack_from("<I", data, opt + 108)
    dirs = [struct.unpack_from("<II", data, opt + 112 + 8 * i) for i in range(ndirs)]
    sections = []
    for i in range(nsections):
        name, vsize, vaddr, rawsize, rawptr = struct.unpack_from("<8sIIII", data, opt + opt_size + 40 * i)
        sections.append((vaddr, max(vsize, rawsize), rawptr))

    def off(rva: int) -> int:
        for vaddr, size, rawptr in sections:
            if vaddr <= rva < vaddr + size:
                return rva - vaddr + rawptr
        raise FormatError(f"RVA {rva:#x} is in no section")

    exports = []
    if ndirs > 0 and dirs[0][0]:
        base = off(dirs[0][0])
        (nnames,) = struct.unpack_from("<I", data, base + 24)  # NumberOfNames
        (names_rva,) = struct.unpack_from("<I", data, base + 32)  # AddressOfNames
        for i in range(nnames):
            (name_rva,) = struct.unpack_from("<I", data, off(names_rva) + 4 * i)
            exports.append(_cstr(data, off(name_rva)))
    libraries, imports = [], {}
    if ndirs > 1 and dirs[1][0]:
        desc = off(dirs[1][0])
        while True:
            lookup, _, _, name_rva, first = struct.unpack_from("<IIIII", data, desc)
            if not (lookup or name_rva or first):
                break
            dll = _cstr(data, off(name_rva))
            libraries.append(dll)
            names = imports.setdefault(dll, [])
            thunk = off(lookup or first)
            while True:
                (entry,) = struct.unpack_from("<Q", data, thunk)
                if entry == 0:
                    break
                if entry >> 63:
                    names.append(f"#{entry & 0xFFFF}")  # by ordinal
                else:
                    names.append(_cstr(data, off(entry & 0x7FFFFFFF) + 2))  # skip the hint
                thunk += 8
            desc += 20
    notes = []
    if ndirs > 13 and dirs[13][0]:
        notes.append("has delay-load imports (not read)")
    return Binary("PE32+", PE_MACHINES.get(machine, hex(machine)),
                  "dll" if characteristics & 0x2000 else "exe", libraries, imports, sorted(exports), notes=notes)


# ------------------------------------------------------------------------------------------------
# Mach-O


MACHO_CPUS = {0x01000007: "x86-64", 0x0100000C: "arm64"}
MACHO_KINDS = {1: "object", 2: "executable", 6: "dylib", 8: "bundle"}
LC_SYMTAB, LC_LOAD_DYLIB, LC_VERSION_MIN_MACOSX, LC_BUILD_VERSION = 0x2, 0xC, 0x24, 0x32
LC_DYLD_INFO, LC_DYLD_INFO_ONLY, LC_DYLD_CHAINED_FIXUPS = 0x22, 0x80000022, 0x80000034
LC_CODE_SIGNATURE = 0x1D
DYLIB_LOADS = {0xC, 0x80000018, 0x8000001F, 0x20, 0x80000023}  # load, weak, reexport, lazy, upward
# special library ordinals of dyld's binding information
SPECIAL_ORDINALS = {0: "(this image)", -1: "(main executable)", -2: DYNAMIC_LOOKUP, -3: "(weak lookup)"}


def _uleb(data: bytes, at: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, at


def _bind_opcodes(data: bytes, start: int, size: int) -> dict[str, int]:
    """{symbol: library ordinal} from a stream of dyld bind opcodes (LC_DYLD_INFO: the bind, weak
    and lazy bind streams): what dyld actually binds each imported symbol to at load time."""
    bound: dict[str, int] = {}
    at, end = start, start + size
    ordinal, name = 0, None
    while at < end:
        byte = data[at]
        at += 1
        op, imm = byte & 0xF0, byte & 0x0F
        if op == 0x10:  # SET_DYLIB_ORDINAL_IMM
            ordinal = imm
        elif op == 0x20:  # SET_DYLIB_ORDINAL_ULEB
            ordinal, at = _uleb(data, at)
        elif op == 0x30:  # SET_DYLIB_SPECIAL_IMM: 0, -1, -2, -3 as a sign-extended nibble
            ordinal = 0 if imm == 0 else (imm | 0xF0) - 0x100
        elif op == 0x40:  # SET_SYMBOL_TRAILING_FLAGS_IMM + name
            name = _cstr(data, at)
            at += len(name.encode()) + 1
        elif op in (0x60, 0x70, 0x80, 0xA0):  # addend, segment+offset, add addr, bind+add addr
            _, at = _uleb(data, at)  # one (S)LEB operand each; its value does not matter here
            if op == 0xA0 and name is not None:
                bound[name] = ordinal
        elif op == 0xC0:  # DO_BIND_ULEB_TIMES_SKIPPING_ULEB
            _, at = _uleb(data, at)
            _, at = _uleb(data, at)
            if name is not None:
                bound[name] = ordinal
        elif op in (0x90, 0xB0):  # DO_BIND, DO_BIND_ADD_ADDR_IMM_SCALED
            if name is not None:
                bound[name] = ordinal
        elif op == 0xD0 and imm == 0:  # THREADED SET_BIND_ORDINAL_TABLE_SIZE_ULEB
            _, at = _uleb(data, at)
        # 0x00 DONE (ends one lazy entry), 0x50 SET_TYPE_IMM, 0xD1 THREADED_APPLY: no operand
    return bound


def _chained_imports(data: bytes, start: int) -> dict[str, int]:
    """{symbol: library ordinal} from LC_DYLD_CHAINED_FIXUPS' import table (newer linkers)."""
    _, _, imports_off, symbols_off, count, fmt, _ = struct.unpack_from("<7I", data, start)
    bound = {}
    for i in range(count):
        if fmt == 3:  # DYLD_CHAINED_IMPORT_ADDEND64: ordinal 16 bits, name offset 32 bits
            (raw,) = struct.unpack_from("<Q", data, start + imports_off + 16 * i)
            ordinal, name_off, width = raw & 0xFFFF, raw >> 32, 16
        else:  # DYLD_CHAINED_IMPORT (4 bytes) / _ADDEND (8 bytes): ordinal 8 bits, offset 23 bits
            (raw,) = struct.unpack_from("<I", data, start + imports_off + (4 if fmt == 1 else 8) * i)
            ordinal, name_off, width = raw & 0xFF, raw >> 9, 8
        if ordinal >= (1 << width) - 15:  # the special ordinals are stored as small negatives
            ordinal -= 1 << width
        bound[_cstr(data, start + symbols_off + name_off)] = ordinal
    return bound


def _version(v: int) -> str:
    return f"{v >> 16}.{(v >> 8) & 0xFF}"


def _macho(data: bytes) -> Binary:
    _, cpu, _, filetype, ncmds, _, flags, _ = struct.unpack_from("<IiiIIIII", data, 0)
    at = 32
    libraries, symtab, min_os, signed = [], None, None, False
    bound: dict[str, int] | None = None
    for _ in range(ncmds):
        cmd, size = struct.unpack_from("<II", data, at)
        if cmd in (LC_DYLD_INFO, LC_DYLD_INFO_ONLY):
            fields = struct.unpack_from("<10I", data, at + 8)
            bound = {}
            for off_, size_ in (fields[2:4], fields[4:6], fields[6:8]):  # bind, weak, lazy
                bound.update(_bind_opcodes(data, off_, size_))
        elif cmd == LC_DYLD_CHAINED_FIXUPS:
            bound = _chained_imports(data, struct.unpack_from("<I", data, at + 8)[0])
        elif cmd in DYLIB_LOADS:
            (name_off,) = struct.unpack_from("<I", data, at + 8)
            libraries.append(_cstr(data, at + name_off))
        elif cmd == LC_SYMTAB:
            symtab = struct.unpack_from("<IIII", data, at + 8)
        elif cmd == LC_CODE_SIGNATURE:
            signed = True
        elif cmd == LC_BUILD_VERSION:
            min_os = _version(struct.unpack_from("<I", data, at + 12)[0])
        elif cmd == LC_VERSION_MIN_MACOSX:
            min_os = _version(struct.unpack_from("<I", data, at + 8)[0])
        at += size
    if symtab is None:
        raise FormatError("no LC_SYMTAB")
    symoff, nsyms, stroff, _ = symtab
    imports: dict[str, list[str]] = {}
    exports = []
    for i in range(nsyms):
        strx, ntype, _, desc, _ = struct.unpack_from("<IBBHQ", data, symoff + 16 * i)
        if ntype & 0xE0 or not ntype & 0x01:  # debugging entries and local symbols
            continue
        raw = _cstr(data, stroff + strx)
        name = raw[1:] if raw.startswith("_") else raw
        if ntype & 0x0E == 0x0:  # N_UNDF: imported
            # dyld binds by the binding information; the symbol table's own ordinal (high byte of
            # n_desc) only counts where there is none
            if bound is not None:
                ordinal = bound.get(raw)
            else:
                ordinal = (desc >> 8) & 0xFF
                ordinal = ordinal - 0x100 if ordinal >= 0xFD else ordinal
            if ordinal is None:
                lib = "(never bound)"
            elif ordinal in SPECIAL_ORDINALS:
                lib = SPECIAL_ORDINALS[ordinal]
            elif 1 <= ordinal <= len(libraries):
                lib = libraries[ordinal - 1]
            else:
                lib = f"(ordinal {ordinal})"
            imports.setdefault(lib, []).append(name)
        elif ntype & 0x0E == 0xE:  # N_SECT: defined here, external
            exports.append(name)
    return Binary("Mach-O", MACHO_CPUS.get(cpu, hex(cpu)), MACHO_KINDS.get(filetype, str(filetype)),
                  libraries, imports, sorted(exports), min_os=min_os, signed=signed)


# ------------------------------------------------------------------------------------------------
# ELF


ELF_MACHINES = {62: "x86-64", 183: "arm64"}


def _elf(data: bytes) -> Binary:
    if data[4] != 2 or data[5] != 1:
        raise FormatError("not a 64-bit little-endian ELF")
    etype, machine = struct.unpack_from("<HH", data, 16)
    shoff, = struct.unpack_from("<Q", data, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", data, 0x3A)
    sections = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + shentsize * i) for i in range(shnum)]
    imports: dict[str, list[str]] = {}
    exports, libraries = [], []
    for _, stype, _, _, offset, size, link, _, _, entsize in sections:
        strtab = sections[link][4] if link < len(sections) else 0
        if stype == 11:  # SHT_DYNSYM
            for i in range(1, size // 24):
                name_off, info, other, shndx, _, _ = struct.unpack_from("<IBBHQQ", data, offset + 24 * i)
                name = _cstr(data, strtab + name_off)
                bind = info >> 4
                if not name or bind not in (1, 2):  # GLOBAL, WEAK
                    continue
                if shndx == 0:
                    imports.setdefault(ANY_LIBRARY, []).append(name)
                elif other & 0x3 == 0:  # default visibility
                    exports.append(name)
        elif stype == 6:  # SHT_DYNAMIC
            for i in range(size // 16):
                tag, val = struct.unpack_from("<qQ", data, offset + 16 * i)
                if tag == 0:
                    break
                if tag == 1:  # DT_NEEDED
                    libraries.append(_cstr(data, strtab + val))
    kind = {3: "shared object", 2: "executable", 1: "relocatable"}.get(etype, str(etype))
    return Binary("ELF", ELF_MACHINES.get(machine, str(machine)), kind, libraries, imports, sorted(exports))


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(arg, json.dumps(asdict(read(arg)), indent=1))
