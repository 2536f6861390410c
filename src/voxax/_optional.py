"""Optional dependencies: import them on first use, with an error that names the extra."""

from __future__ import annotations

import importlib
import warnings

__all__ = ["EXTRAS", "require"]

#: The extra of `pip install "voxax[<extra>]"` that provides each optional module.
EXTRAS = {
    "matplotlib": "plot",
    "plotly": "plot",
    "jaxopt": "bounds",
}


def require(module: str, feature: str):
    """Imports `module` for `feature`, or raises an ImportError naming the extra to install.

    **Arguments:**

    - `module`: the module to import, e.g. `"matplotlib.pyplot"`.
    - `feature`: what needs it, for the message (e.g. `"voxax.plot"`).

    **Returns:** the imported module.
    """
    top = module.split(".")[0]
    extra = EXTRAS[top]
    try:
        with warnings.catch_warnings():
            if top == "jaxopt":
                # jaxopt announces on import that it is in maintenance mode; voxax uses
                # one stable solver from it.
                warnings.filterwarnings("ignore", message="JAXopt is no longer maintained", category=DeprecationWarning)
            return importlib.import_module(module)
    except ImportError as err:
        raise ImportError(
            f'{feature} needs {top}, an optional dependency: pip install "voxax[{extra}]" (or pip install {top})'
        ) from err
