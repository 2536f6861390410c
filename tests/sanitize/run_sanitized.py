"""Builds the voxax kernels with AddressSanitizer + UBSan and fuzzes them.

    python tests/sanitize/run_sanitized.py [--build-dir DIR] [driver options, e.g. --inputs 1500]

1. Configures and builds the kernels with `-DVOXAX_SANITIZE=ON` (cmake + ninja, against the
   XLA FFI headers of the running Python's jax, `jax.ffi.include_dir()`) into a cached build directory
   (`$VOXAX_SANITIZE_BUILD_DIR`, else `<tmp>/voxax-sanitize-<hash>`); ninja rebuilds only
   when `csrc/` changed.
2. Runs `driver.py` in a subprocess with the compiler's `libasan.so` and `libubsan.so` in
   `LD_PRELOAD`, `VOXAX_KERNELS` pointing at the sanitized library,
   `ASAN_OPTIONS=detect_leaks=0:abort_on_error=1` (leak detection is off: the Python
   interpreter itself never frees some memory) and
   `UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1`, and `NPROC=4` so that XLA's thread
   pool (which the kernels use) has more threads than a 2-core CI machine has cores.

The exit status is the driver's: 0 when every input passed, 3 when a value check failed
(see the driver's output), and an abort (-6 / 134) on a sanitizer finding, whose report
("ERROR: AddressSanitizer ..." or "... runtime error: ...") is on stderr.
`--canary` instead runs a deliberate heap overflow under the same set-up, to show that
findings are detected. The test `tests/test_sanitizers.py` runs this script.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
DRIVER = HERE / "driver.py"
LIBRARY = "libvoxax_kernels.so"

ASAN_OPTIONS = "detect_leaks=0:abort_on_error=1"
UBSAN_OPTIONS = "print_stacktrace=1:halt_on_error=1"

CANARY = """
import ctypes
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
p = libc.malloc(16)
ctypes.string_at(p, 64)  # reads 48 bytes past the allocation
print("canary: no sanitizer report")
"""


def find_compiler() -> str | None:
    for name in (os.environ.get("CXX"), "g++", "c++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def missing_tools() -> list[str]:
    """The build tools this script needs that are not installed (empty when all are)."""
    missing = [tool for tool in ("cmake", "ninja") if shutil.which(tool) is None]
    if find_compiler() is None:
        missing.append("a C++ compiler (g++)")
    return missing


def ffi_include() -> str:
    import jax

    return jax.ffi.include_dir()


def default_build_dir() -> Path:
    env = os.environ.get("VOXAX_SANITIZE_BUILD_DIR")
    if env:
        return Path(env)
    import jaxlib

    key = f"{ROOT}|{sys.executable}|{jaxlib.__version__}|{find_compiler()}"
    digest = hashlib.sha1(key.encode()).hexdigest()[:12]
    return Path(tempfile.gettempdir()) / f"voxax-sanitize-{digest}"


def build(build_dir: Path) -> Path:
    """Configures (once) and builds the sanitized kernels; returns the library's path."""
    cxx = find_compiler()
    build_dir.mkdir(parents=True, exist_ok=True)
    cache = build_dir / "CMakeCache.txt"
    configured = cache.is_file() and (build_dir / "build.ninja").is_file()
    if configured:
        text = cache.read_text(errors="replace")
        configured = f"CMAKE_HOME_DIRECTORY:INTERNAL={ROOT}" in text and "VOXAX_SANITIZE:BOOL=ON" in text
    if not configured:
        if cache.exists():
            cache.unlink()
        cmd = [
            "cmake", "-S", str(ROOT), "-B", str(build_dir), "-G", "Ninja",
            "-DVOXAX_SANITIZE=ON",
            f"-DCMAKE_CXX_COMPILER={cxx}",
            f"-DPython3_EXECUTABLE={sys.executable}",
            f"-DXLA_FFI_INCLUDE_DIR={ffi_include()}",
        ]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    subprocess.run(["cmake", "--build", str(build_dir)], check=True)
    lib = build_dir / LIBRARY
    data = lib.read_bytes()
    if b"__asan_report" not in data or b"__ubsan_handle" not in data:
        raise RuntimeError(f"{lib} is not instrumented with ASan and UBSan")
    return lib


def runtime_library(name: str) -> str:
    """The sanitizer runtime (libasan.so, libubsan.so) of the compiler that built the kernels."""
    out = subprocess.run([find_compiler(), f"-print-file-name={name}"], capture_output=True, text=True, check=True)
    path = out.stdout.strip()
    if not os.path.isabs(path) or not os.path.exists(path):
        raise RuntimeError(
            f"the compiler {find_compiler()} has no {name} (got {path!r}); the sanitized build needs "
            "GCC's sanitizer runtimes (install libasan/libubsan, or set CXX=g++)"
        )
    return os.path.realpath(path)


def sanitizer_env(lib: Path) -> dict:
    env = dict(os.environ)
    env["LD_PRELOAD"] = ":".join([runtime_library("libasan.so"), runtime_library("libubsan.so")])
    env["ASAN_OPTIONS"] = ASAN_OPTIONS
    env["UBSAN_OPTIONS"] = UBSAN_OPTIONS
    env["VOXAX_KERNELS"] = str(lib)
    env["NPROC"] = env.get("VOXAX_SANITIZE_NPROC", "4")
    env.pop("PJRT_NPROC", None)
    env["PYTHONPATH"] = os.pathsep.join(p for p in [str(ROOT / "src"), env.get("PYTHONPATH", "")] if p)
    env.setdefault("JAX_PLATFORMS", "cpu")
    return env


SANITIZER_REPORT = re.compile(r"ERROR: AddressSanitizer|runtime error:|ERROR: LeakSanitizer|UndefinedBehaviorSanitizer")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Builds the kernels with ASan+UBSan and runs the fuzz driver.")
    parser.add_argument("--build-dir", type=Path, default=None)
    parser.add_argument("--canary", action="store_true", help="run a deliberate heap overflow instead of the driver")
    args, driver_args = parser.parse_known_args(argv)
    missing = missing_tools()
    if missing:
        print("run_sanitized: missing " + ", ".join(missing), file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    lib = build(args.build_dir or default_build_dir())
    t_build = time.perf_counter() - t0
    print(f"sanitized kernels: {lib} (configure + build {t_build:.1f} s)", flush=True)
    env = sanitizer_env(lib)
    cmd = [sys.executable, "-c", CANARY] if args.canary else [sys.executable, str(DRIVER), *driver_args]
    t1 = time.perf_counter()
    rc = subprocess.run(cmd, env=env, cwd=str(ROOT)).returncode
    print(f"driver exit status {rc}; driver {time.perf_counter() - t1:.1f} s, total {time.perf_counter() - t0:.1f} s",
          flush=True)
    return rc


if __name__ == "__main__":
    sys.exit(main())
