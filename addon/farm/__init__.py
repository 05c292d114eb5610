"""`tearcloth farm`: many bakes (files x objects x wedges of settings) as tasks on Dask.

What each file owns (none imports Blender; Blender runs only in each task's subprocesses):

* ``plan``   ``--set`` read against the settings table, the task list, folders, scheduler checks
* ``task``   ``run_task``, what a worker runs: the wedge variation and ``tearcloth bake`` as
             fresh subprocesses, progress events, cancel, retry on failure
* ``run``    the client: the local cluster (127.0.0.1) or a remote scheduler (TLS), the progress
             bar, Ctrl-C, the manifest
* ``sheet``  the wedge contact sheet (matplotlib)

The Blender half (list a file's objects, write a variation) is ``tearcloth.blender.wedge``.
Dask (``distributed``) is an optional dependency: ``pip install 'tearcloth[farm]'``.
"""
