"""Per-pixel reflectance maps (docs/maps.md), at the fitting layer: step 2 at every pixel of
a photo stack through a fixed medium.

- :mod:`.grid`: the tabulated nonlinear parameters and the cubic B-spline over them;
- :mod:`.tables`: the basis columns at every node, built once per acquisition;
- :mod:`.solve`: every pixel against the tables, vectorized in JAX, on the rules of
  :mod:`veil.fitting.least_squares`;
- :mod:`.channels`, :mod:`.solve_channels`: maps of several colour channels at once (each
  channel's medium and tables; every pixel's channels one problem, the scales per channel);
- :mod:`.near`: near-field geometry (per-pixel angles, the field grid);
- :mod:`.photos`: the photos, the acquisition and its staging;
- :mod:`.store`: the Zarr store (its layout, checks, lock, reading);
- :mod:`.run`: the run over Dask tiles, resumable (:func:`veil.fit_maps`); :mod:`.tile`:
  one tile solved and written, the store's attributes;
- :mod:`.show`: the maps as a figure and as TIFF/EXR files.

Nothing is imported here: the submodules import JAX, Dask or Zarr where they need them.
"""
