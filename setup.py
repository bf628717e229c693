"""The compiled per-tick arithmetic of the 6-DOF contact (dockhil/contact/_rigid.c) and message
screen (dockhil/runtime/_screen.c); the rest is in pyproject.toml.

Optional: where they do not build (no C compiler), dockhil runs their Python twins, which give the
same answers, more slowly."""

from setuptools import Extension, setup

# The same bits as the Python twin: no fused multiply-add, and sin/cos from the C library one by
# one (see the file's head).
FLAGS = ["-O2", "-ffp-contract=off", "-fno-builtin", "-fno-fast-math"]

setup(
    ext_modules=[
        Extension("dockhil.contact._rigid", ["dockhil/contact/_rigid.c"], extra_compile_args=FLAGS, optional=True),
        # A composed run's message screen (dockhil/runtime/_screen.c; screen.bounds_check is its twin).
        Extension("dockhil.runtime._screen", ["dockhil/runtime/_screen.c"], extra_compile_args=FLAGS, optional=True),
    ]
)
