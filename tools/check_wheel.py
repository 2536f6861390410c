"""Checks a built voxax wheel (or sdist) without installing it (run by tools/build_wheel).

- It holds the package and exactly one kernel library, a regular file (not a link).
- The kernels are a portable build: `voxax_cpu_features` (csrc/common/cpu_features.cc)
  reports no instruction-set extension enabled throughout the library, and on x86-64 Linux
  the AVX2 clones compiled in (chosen at run time). On x86-64, where objdump is installed,
  the disassembly agrees: AVX instructions (VEX or EVEX encoded, ymm or zmm registers)
  appear only in the functions' AVX2 clones (`<name>.avx2...`, or functions compiled for AVX2 and named `..._avx2`, chosen at run time).

With `--sdist`: the sdist holds what a build from it needs (CMakeLists.txt, csrc/, the
package, the metadata's README, LICENSE and CHANGELOG.md) and no build output (compiled
libraries, build folders).

Exits with status 1 and a message on the first failure.

    python tools/check_wheel.py WHEEL
    python tools/check_wheel.py --sdist SDIST
"""

from __future__ import annotations

import ctypes
import platform
import re
import shutil
import stat
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from pathlib import Path

# Where `voxax_cpu_features` writes its values (see csrc/common/cpu_features.cc and
# voxax/_kernels/cpu.py).
_FEATURES = ("sse4.2", "avx", "avx2", "fma", "avx512f")
_COUNT = 2 + 2 * len(_FEATURES) + 1


def fail(message: str) -> None:
    print(f"tools/check_wheel.py: {message}", file=sys.stderr)
    sys.exit(1)


_FUNCTION = re.compile(r"^[0-9a-f]+ <(.+)>:$")
_AVX = re.compile(r"\tv[a-z0-9]+\s|%[yz]mm")


def avx_outside_clones(library: str) -> dict[str, int] | None:
    """The functions other than AVX2 clones with AVX instructions, and how many each has
    (None without objdump)."""
    objdump = shutil.which("objdump")
    if objdump is None:
        return None
    text = subprocess.run([objdump, "-d", "--no-show-raw-insn", library], check=True, capture_output=True,
                          text=True).stdout
    found: dict[str, int] = {}
    function = "?"
    for line in text.splitlines():
        match = _FUNCTION.match(line)
        if match:
            function = match.group(1)
        elif _AVX.search(line) and ".avx2" not in function and "_avx2" not in function:
            found[function] = found.get(function, 0) + 1
    return found


def main(wheel: str) -> None:
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        if "voxax/__init__.py" not in names:
            fail(f"{wheel} has no voxax/__init__.py")
        libraries = [n for n in names if Path(n).name.startswith("libvoxax_kernels")]
        if len(libraries) != 1 or libraries[0] != "voxax/libvoxax_kernels.so":
            fail(f"expected one voxax/libvoxax_kernels.so in the wheel, found {libraries}")
        info = zf.getinfo(libraries[0])
        if stat.S_ISLNK(info.external_attr >> 16):
            fail(f"{libraries[0]} is a symbolic link in the wheel")
        stray = [n for n in names if n.startswith(("build/", "tests/", "csrc/")) or "/__pycache__/" in n]
        if stray:
            fail(f"the wheel holds files outside the package: {stray[:5]}")
        with tempfile.TemporaryDirectory() as tmp:
            path = zf.extract(libraries[0], tmp)
            lib = ctypes.CDLL(path)
            fn = lib.voxax_cpu_features
            fn.restype, fn.argtypes = ctypes.c_int, [ctypes.POINTER(ctypes.c_int32), ctypes.c_int]
            count = fn(None, 0)
            if count != _COUNT:
                fail(f"voxax_cpu_features reports {count} values, expected {_COUNT}")
            values = (ctypes.c_int32 * count)()
            fn(values, count)
            on_x86 = platform.machine() in ("x86_64", "AMD64")
            avx = avx_outside_clones(path) if on_x86 else None
    built = [name for name, flag in zip(_FEATURES, values[2:2 + len(_FEATURES)]) if flag]
    if built:
        fail(f"the kernels are compiled with {', '.join(built)} throughout: not portable (drop -march/-m flags)")
    on_x86_linux = platform.machine() in ("x86_64", "AMD64") and sys.platform.startswith("linux")
    if on_x86_linux and not values[0]:
        fail("the AVX2 clones are not compiled in")
    if avx:
        fail(f"AVX instructions outside the AVX2 clones: {sorted(avx.items(), key=lambda kv: -kv[1])[:5]}")
    scan = ("no AVX instruction outside the AVX2 clones (objdump)" if avx is not None
            else "instruction scan skipped (no objdump, or not x86-64)")
    print(f"{Path(wheel).name}: {len(names)} files, kernels for the baseline instruction set, "
          f"AVX2 clones {'compiled in' if values[0] else 'not applicable here'}, {scan}")


def check_sdist(sdist: str) -> None:
    with tarfile.open(sdist) as tf:
        names = tf.getnames()
    top = names[0].split("/")[0]
    files = {n[len(top) + 1:] for n in names if n.startswith(top + "/")}
    needed = ["pyproject.toml", "CMakeLists.txt", "README.md", "LICENSE", "CHANGELOG.md", "PKG-INFO",
              "src/voxax/__init__.py", "csrc/common/cpu_features.cc", "tools/smoke_test.py"]
    missing = [n for n in needed if n not in files]
    if missing:
        fail(f"the sdist lacks {missing}")
    sources = [n for n in files if n.startswith("csrc/") and n.endswith(".cc")]
    built = [n for n in files if n.endswith((".so", ".o", ".dylib")) or n.startswith(("build/", ".venv/", "site/"))]
    if built:
        fail(f"the sdist holds build output: {sorted(built)[:5]}")
    print(f"{Path(sdist).name}: {len(files)} files, {len(sources)} C++ sources, no build output")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--sdist":
        check_sdist(sys.argv[2])
    elif len(sys.argv) == 2:
        main(sys.argv[1])
    else:
        fail("usage: python tools/check_wheel.py [--sdist] FILE")
