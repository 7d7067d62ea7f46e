from threadpoolctl import threadpool_info

from gonio.campaign.blas import single_thread_blas


def _blas_threads():
    return sorted((d["filepath"], d["num_threads"]) for d in threadpool_info()
                  if d["user_api"] == "blas")  # fmt: skip


def test_single_thread_blas_inside_and_restored_after():
    import numpy as np

    @single_thread_blas
    def work(n):
        """doc"""
        inside = _blas_threads()
        a = np.ones((n, n))
        return inside, float((a @ a)[0, 0])

    import scipy.linalg  # noqa: F401  (so that the before/after lists compare the same libs)

    before = _blas_threads()
    inside, v = work(64)
    assert v == 64.0 and work.__doc__ == "doc" and work.__name__ == "work"
    assert inside and all(n == 1 for _, n in inside)
    assert _blas_threads() == before
