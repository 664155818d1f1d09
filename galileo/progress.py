"""Progress bars: tqdm with a thread lock instead of its default multiprocessing lock.

tqdm's first bar in a process creates a class-wide `multiprocessing.RLock`, a named POSIX
semaphore registered with the process tree's resource tracker. Galileo draws bars in one
process only, but its code also runs inside Dask and chain worker processes; a worker that
is stopped abruptly (a cluster shut down by Ctrl-C on a busy machine kills a worker that
does not exit in time) never unlinks that semaphore, and the resource tracker then prints
"There appear to be 1 leaked semaphore objects" after the command's one line. A thread
lock is all a single process's bars need, and leaves nothing behind. Import `tqdm` from
here, never from tqdm itself.
"""
import threading

from tqdm import tqdm

tqdm.set_lock(threading.RLock())

__all__ = ["tqdm"]
