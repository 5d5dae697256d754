"""apps.compile_once: a kernel another process is compiling is loaded from the cache, not compiled again."""

import fcntl
import subprocess
import sys
import textwrap
import time

import pytest

MODULE = textwrap.dedent("""
    import numba

    @numba.njit(cache=True)
    def kernel(x):
        return 2 * x + 1
""")

CHILD = textwrap.dedent("""
    import sys
    sys.path.insert(0, sys.argv[1])
    from numba.core import event
    if sys.argv[3] == "locks":
        from apps.compile_once import install
        install(sys.argv[2])
    compiles = []

    class Count(event.Listener):
        def on_start(self, e):
            compiles.append(e)

        def on_end(self, e):
            pass

    event.register("numba:compile", Count())
    import kernel_module
    print("ready", flush=True)
    sys.stdin.readline()  # the parent holds the kernel's lock and compiles it now
    assert kernel_module.kernel(3) == 7
    print(len(compiles), flush=True)
""")


def _child_compiles(tmp_path, mode: str) -> int:
    """The parent holds the kernel's lock; the child is told to call the kernel; the parent then
    compiles and caches it itself and releases the lock ("plain": after the child is done, the
    child without locks). How often the child compiled."""
    src = tmp_path / mode
    src.mkdir()
    (src / "kernel_module.py").write_text(MODULE)
    locks = tmp_path / f"locks_{mode}"
    locks.mkdir()
    with open(locks / "kernel_module.kernel.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(src), str(locks), mode], stdin=subprocess.PIPE,
                                 stdout=subprocess.PIPE, text=True)
        assert child.stdout.readline().strip() == "ready"
        child.stdin.write("go\n")
        child.stdin.flush()
        if mode == "plain":
            out, _ = child.communicate(timeout=120)  # nothing to wait for: it compiles the kernel itself
        else:
            time.sleep(0.5)  # the child reaches the kernel and waits for this process's lock
        sys.path.insert(0, str(src))
        try:
            import kernel_module

            assert kernel_module.kernel(3) == 7  # compiled here and saved to the cache
        finally:
            sys.path.remove(str(src))
            sys.modules.pop("kernel_module", None)
    if mode != "plain":
        out, _ = child.communicate(timeout=120)
    assert child.returncode == 0
    return int(out.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_kernel_another_process_is_compiling_is_loaded_not_compiled(tmp_path):
    # With the locks the child waits for the parent and loads its result, however slow either is.
    assert _child_compiles(tmp_path, "locks") == 0
    # Without them it compiles the kernel itself: the count above would be 1 (the check can fail).
    assert _child_compiles(tmp_path, "plain") == 1
