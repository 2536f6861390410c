"""`voxax.show_config()`: the version, the kernel library and the paths this machine takes."""

from __future__ import annotations

import os
import platform
import sys

__all__ = ["describe", "show_config"]


def _threads_rule(hardware_threads: int) -> str:
    cores = f"all {hardware_threads} hardware threads" if hardware_threads > 0 else "all cores"
    env = os.environ.get("VOXAX_NUM_THREADS")
    if not env:
        host = f"VOXAX_NUM_THREADS unset: {cores}"
    else:
        try:
            n = int(env)
        except ValueError:
            host = f"VOXAX_NUM_THREADS={env!r} is not an integer: calls without `threads` raise ValueError"
        else:
            host = f"VOXAX_NUM_THREADS={n}: {min(n, 256)} threads" if n > 0 else f"VOXAX_NUM_THREADS={n}: {cores}"
    return f"{host} (eager host calls without `threads`); jit-compiled kernels use XLA's CPU thread pool"


def _flags(cpu: dict) -> str:
    if all(v is None for v in cpu.values()):
        return f"{platform.machine()} (the x86-64 extensions do not apply)"
    return ", ".join(f"{name} {'yes' if has else 'no'}" for name, has in cpu.items())


def _path(path) -> str:
    real = os.path.realpath(path)
    return str(path) if real == os.path.abspath(path) else f"{path} -> {real}"


def describe() -> str:
    """The text `show_config` prints."""
    import jax
    import jaxlib

    import voxax

    from ._kernels import library_path
    from ._kernels.cpu import cpu_features

    info = cpu_features()
    if info["built_with"]:
        build = (f"compiled with {', '.join(info['built_with'])} throughout: runs only on CPUs that have them "
                 "(not a portable build)")
    else:
        build = f"portable ({platform.machine()} baseline, wider vectors chosen at run time)"
    if not info["clones_built"]:
        clones = "not compiled in (not x86-64 Linux, or a sanitizer build): the plain code everywhere"
    elif info["avx2_clones"]:
        clones = "compiled in, selected on this CPU (it has AVX2)"
    else:
        clones = "compiled in, not selected (this CPU lacks AVX2): the default clones"
    rows = [
        ("version", voxax.__version__),
        ("package", os.path.dirname(os.path.abspath(voxax.__file__))),
        ("kernels", _path(library_path())),
        ("build", build),
        ("AVX2 clones", clones),
        ("CPU", _flags(info["cpu"])),
        ("threads", _threads_rule(info["hardware_threads"])),
        ("python", f"{platform.python_version()} ({sys.executable})"),
        ("jax", jax.__version__),
        ("jaxlib", jaxlib.__version__),
        ("platform", platform.platform()),
    ]
    width = max(len(name) for name, _ in rows)
    return "\n".join([f"voxax {voxax.__version__}"] + [f"  {name:<{width}}  {value}" for name, value in rows])


def show_config(file=None) -> None:
    """Prints how this voxax is built and what it uses on the running machine.

    The version, the package and kernel library paths, whether the kernels are a portable
    build, whether the AVX2 clones of the vectorised kernels are compiled in and selected
    on this CPU (and which x86-64 extensions the CPU has), the thread-count rule
    (`VOXAX_NUM_THREADS`), and the Python, jax and jaxlib versions. Include it in bug
    reports; `voxax --version --verbose` prints the same.

    **Arguments:**

    - `file`: a text stream to write to (default `sys.stdout`).

    **Example:**

    ```python
    >>> import voxax
    >>> voxax.show_config()
    voxax ...
      version      ...
      package      ...
      kernels      ...libvoxax_kernels...
    ```
    """
    if file is not None and not callable(getattr(file, "write", None)):
        raise TypeError(f"voxax.show_config: `file` must be a text stream (with .write) or None, got "
                        f"{type(file).__name__}")
    print(describe(), file=sys.stdout if file is None else file)
