#!/usr/bin/env python3
"""Build the reference sketch for an Arduino Uno and the simavr rig that runs it.

    python3 firmware/emulator/build.py [--baud 115200] [--counts-per-rev N] [--json]

Two products, each cached by the content hash of everything that goes into it
(sources, flags, the compilers' versions, the Arduino core, the simavr headers):

* ``pmdc_board.elf``: ``firmware/arduino/pmdc_board/pmdc_board.ino`` and the protocol
  core compiled with avr-gcc/avr-g++ for the ATmega328P at 16 MHz, against the
  Arduino AVR core of Debian's ``arduino-core-avr`` (the flags of its
  ``platform.txt``: -Os, LTO, gc-sections), the core archived as the IDE does so
  only what the sketch uses is linked. One build per baud (``PMDC_BAUD``) and
  counts per revolution.
* ``pmdc_emu``: ``firmware/emulator/pmdc_emu.c`` linked with libsimavr (the motor,
  the sensors, the encoder and the pty bridge around the emulated MCU).

The cache lives outside the source tree: ``$PMDC_FIRMWARE_CACHE``, else
``$XDG_CACHE_HOME/pmdc_ident/firmware``, else ``~/.cache/pmdc_ident/firmware``.
A product is built in a temporary folder and renamed into place, so a cache
entry is complete or absent, and two builds racing each other are harmless.
Needs: ``apt-get install gcc-avr avr-libc arduino-core-avr libsimavr-dev``
(``simavr`` and ``libsimavrparts1`` come with them or are handy). Exit status 3
with one line when a tool is missing, 1 when a compiler fails.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

HERE = Path(__file__).resolve().parent
FIRMWARE = HERE.parent
SKETCH = FIRMWARE / "arduino" / "pmdc_board" / "pmdc_board.ino"
PROTOCOL = FIRMWARE / "protocol"
EMULATOR_SRC = HERE / "pmdc_emu.c"
ARDUINO_AVR = Path(os.environ.get("PMDC_ARDUINO_AVR", "/usr/share/arduino/hardware/arduino/avr"))
SIMAVR_INCLUDE = Path("/usr/include/simavr")
APT_HINT = "apt-get install gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev"

MCU = "atmega328p"
F_CPU = 16_000_000
COMMON = [
    f"-mmcu={MCU}",
    f"-DF_CPU={F_CPU}L",
    "-DARDUINO=10807",
    "-DARDUINO_AVR_UNO",
    "-DARDUINO_ARCH_AVR",
    "-g",
    "-Os",
    "-flto",
    "-ffunction-sections",
    "-fdata-sections",
]
CFLAGS = ["-std=gnu11", "-fno-fat-lto-objects"]
CXXFLAGS = [
    "-std=gnu++11",
    "-fpermissive",
    "-fno-exceptions",
    "-fno-threadsafe-statics",
    "-Wno-error=narrowing",
]
LDFLAGS = [f"-mmcu={MCU}", "-Os", "-g", "-flto", "-fuse-linker-plugin", "-Wl,--gc-sections"]
STRICT = ["-Wall", "-Wextra", "-Werror"]
# WString.cpp needs DECIMAL_DIG, which Debian's avr-gcc 5.4 float.h lacks; the
# sketch uses no String, so the core archive goes without it.
CORE_SKIP = {"WString.cpp"}
EMU_CFLAGS = [
    "-std=gnu11",
    "-O2",
    "-pthread",
    "-Wall",
    "-Wextra",
    "-Werror",
    "-Wno-unused-parameter",
]


class BuildError(Exception):
    def __init__(self, message: str, status: int = 1) -> None:
        super().__init__(message)
        self.status = status


def cache_root() -> Path:
    env = os.environ.get("PMDC_FIRMWARE_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "pmdc_ident" / "firmware"


def _need(tool: str) -> str:
    path = shutil.which(tool)
    if path is None:
        raise BuildError(f"{tool} not found: {APT_HINT}", status=3)
    return path


def _version(tool: str) -> str:
    r = subprocess.run([tool, "--version"], capture_output=True, text=True, check=False)
    return r.stdout.splitlines()[0] if r.stdout else tool


def _hash_files(h: hashlib._Hash, files: list[Path]) -> None:
    for f in sorted(files):
        h.update(str(f.name).encode() + b"\0")
        h.update(f.read_bytes())


def _arduino_core() -> tuple[Path, Path]:
    core = ARDUINO_AVR / "cores" / "arduino"
    variant = ARDUINO_AVR / "variants" / "standard"
    if not (core / "Arduino.h").is_file():
        raise BuildError(f"Arduino AVR core not found in {ARDUINO_AVR}: {APT_HINT}", status=3)
    return core, variant


def _run(cmd: list[str], cwd: Path) -> None:
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        text = (r.stderr or r.stdout).strip().splitlines()
        detail = "\n".join(text[-15:])
        raise BuildError(f"build failed: {' '.join(cmd[:2])} ...\n{detail}")


def _publish(tmp: Path, final: Path) -> None:
    """Rename a finished build into place (a racing build that won is kept)."""
    try:
        os.rename(tmp, final)
    except OSError:
        if not final.is_dir():
            raise
        shutil.rmtree(tmp, ignore_errors=True)


def _cached(
    root: Path, kind: str, digest: str, name: str, make: Callable[[Path], None]
) -> tuple[Path, bool]:
    """``root/<kind>-<digest>/<name>``: from the cache, else made by ``make(tmp)`` in a
    temporary folder that is renamed into place; (path, True if it came from the cache)."""
    final = root / f"{kind}-{digest[:20]}"
    product = final / name
    if product.is_file():
        return product, True
    root.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{kind}-", dir=root))
    try:
        make(tmp)
        _publish(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return product, False


def _core_objects(work: Path, core: Path, variant: Path) -> Path:
    """The Arduino core as an archive, as the IDE links it."""
    inc = [f"-I{core}", f"-I{variant}"]
    objs = []
    for src in sorted(core.iterdir()):
        if src.name in CORE_SKIP or src.suffix not in (".c", ".cpp", ".S"):
            continue
        out = work / f"core_{src.name}.o"
        if src.suffix == ".c":
            cmd = ["avr-gcc", *COMMON, *CFLAGS, *inc, "-c", str(src), "-o", str(out)]
        elif src.suffix == ".cpp":
            cmd = ["avr-g++", *COMMON, *CXXFLAGS, *inc, "-c", str(src), "-o", str(out)]
        else:
            cmd = ["avr-gcc", *COMMON, "-x", "assembler-with-cpp", *inc, "-c", str(src)]
            cmd += ["-o", str(out)]
        _run(cmd, work)
        objs.append(str(out))
    archive = work / "core.a"
    _run(["avr-gcc-ar", "rcs", str(archive), *objs], work)
    return archive


def build_sketch(baud: int, counts_per_rev: int | None, root: Path) -> tuple[Path, bool]:
    """pmdc_board.elf for this baud; (path, True if it came from the cache)."""
    for tool in ("avr-gcc", "avr-g++", "avr-gcc-ar", "avr-size"):
        _need(tool)
    core, variant = _arduino_core()
    defines = [f"-DPMDC_BAUD={int(baud)}UL"]
    if counts_per_rev:
        defines.append(f"-DPMDC_COUNTS_PER_REV={int(counts_per_rev)}UL")
    h = hashlib.sha256()
    h.update(json.dumps([COMMON, CFLAGS, CXXFLAGS, LDFLAGS, STRICT, defines]).encode())
    h.update(_version("avr-gcc").encode())
    _hash_files(h, [SKETCH, *PROTOCOL.glob("pmdc_protocol.*"), Path(__file__).resolve()])
    _hash_files(h, [p for p in core.iterdir() if p.is_file()] + [variant / "pins_arduino.h"])

    def make(tmp: Path) -> None:
        archive = _core_objects(tmp, core, variant)
        inc = [f"-I{core}", f"-I{variant}", f"-I{PROTOCOL}"]
        sketch_o, proto_o = tmp / "sketch.o", tmp / "pmdc_protocol.o"
        # The .ino is C++ that already includes Arduino.h and declares before use, so
        # it compiles as it is (no IDE prototype generation needed).
        cmd = ["avr-g++", *COMMON, *CXXFLAGS, *STRICT, *defines, *inc, "-x", "c++"]
        _run([*cmd, "-c", str(SKETCH), "-o", str(sketch_o)], tmp)
        cmd = ["avr-gcc", *COMMON, *CFLAGS, *STRICT, *inc, "-c", str(PROTOCOL / "pmdc_protocol.c")]
        _run([*cmd, "-o", str(proto_o)], tmp)
        out = tmp / "pmdc_board.elf"
        link = ["avr-gcc", *LDFLAGS, str(sketch_o), str(proto_o), str(archive), "-lm"]
        _run([*link, "-o", str(out)], tmp)
        size = subprocess.run(["avr-size", str(out)], capture_output=True, text=True, check=True)
        (tmp / "size.txt").write_text(size.stdout)
        text, data, bss = (int(x) for x in size.stdout.splitlines()[1].split()[:3])
        if text + data > 32256 or data + bss > 1536:
            msg = f"sketch too big for an Uno: flash {text + data} B, RAM {data + bss} B"
            raise BuildError(msg)
        for f in tmp.glob("*.o"):
            f.unlink()

    return _cached(root, "sketch", h.hexdigest(), "pmdc_board.elf", make)


def build_emulator(root: Path) -> tuple[Path, bool]:
    """The pmdc_emu host program (libsimavr); (path, True if cached)."""
    cc = _need("gcc")
    if not (SIMAVR_INCLUDE / "sim_avr.h").is_file():
        raise BuildError(f"simavr headers not found in {SIMAVR_INCLUDE}: {APT_HINT}", status=3)
    h = hashlib.sha256()
    h.update(json.dumps(EMU_CFLAGS).encode())
    h.update(_version(cc).encode())
    _hash_files(h, [EMULATOR_SRC, Path(__file__).resolve(), *SIMAVR_INCLUDE.glob("*.h")])
    _hash_files(h, list(PROTOCOL.glob("pmdc_protocol.*")))

    def make(tmp: Path) -> None:
        srcs = [str(EMULATOR_SRC), str(PROTOCOL / "pmdc_protocol.c")]
        inc = [f"-I{SIMAVR_INCLUDE}", f"-I{PROTOCOL}"]
        cmd = [cc, *EMU_CFLAGS, *inc, *srcs, "-o", str(tmp / "pmdc_emu")]
        _run([*cmd, "-lsimavr", "-lm", "-pthread"], tmp)

    return _cached(root, "emu", h.hexdigest(), "pmdc_emu", make)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baud", type=int, default=115200, help="PMDC_BAUD of the sketch")
    parser.add_argument(
        "--counts-per-rev", type=int, default=0, help="PMDC_COUNTS_PER_REV (0: the sketch's)"
    )
    parser.add_argument("--cache", type=Path, default=None, help="cache folder")
    parser.add_argument("--json", action="store_true", help="print the paths as JSON")
    args = parser.parse_args(argv)
    if not 300 <= args.baud <= 2_000_000:
        print(f"build.py: --baud must be within 300..2000000, got {args.baud}", file=sys.stderr)
        return 2
    root = args.cache or cache_root()
    try:
        elf, elf_cached = build_sketch(args.baud, args.counts_per_rev or None, root)
        emu, emu_cached = build_emulator(root)
    except BuildError as exc:
        print(f"build.py: {exc}", file=sys.stderr)
        return exc.status
    except OSError as exc:
        print(f"build.py: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(
            json.dumps(
                {"elf": str(elf), "emulator": str(emu), "cached": elf_cached and emu_cached}
            )
        )
    else:
        state = "cached" if elf_cached and emu_cached else "built"
        print(f"{state}: {elf}\n        {emu}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
