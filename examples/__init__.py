"""Example scenes and the scripts that study them. The scenes ship with evsda as ``library:examples/NAME.yaml``
(``evsda run library:examples/iss_pass.yaml -o a.zarr`` works after ``pip install``)."""
