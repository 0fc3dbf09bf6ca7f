"""Build hook: ship maps/ and configs/ inside the package (as qpatrol/data/...).

Everything else about the package is in pyproject.toml. The shipped maps and configs
stay at the top of the checkout, where the README and the tests name them; this hook
copies them into the wheel so that an installed qpatrol finds them too
(``qpatrol.maps.shipped_dir``).
"""

from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
DATA = {"maps": ("*.txt", "LICENSE*"), "configs": ("*.yaml",)}


class build_py_with_data(build_py):
    """``build_py`` that also copies the shipped maps and configs into the package."""

    def run(self) -> None:
        super().run()
        for folder, patterns in DATA.items():
            target = Path(self.build_lib) / "qpatrol" / "data" / folder
            self.mkpath(str(target))
            for pattern in patterns:
                for src in sorted((HERE / folder).glob(pattern)):
                    self.copy_file(str(src), str(target / src.name))


setup(cmdclass={"build_py": build_py_with_data})
