"""Rule sweep_gather: all points of a sweep into one netCDF (swept parameters as dimensions), CSV and figure."""
from calib.core import progress as runlog
from calib.studies import sweep_summary
from calib.io.netcdf import provenance

p = snakemake.params
o = snakemake.output
with runlog.to_file(snakemake.log[0]):
    sweep_summary.gather(p.kind, snakemake.wildcards.sweep, list(snakemake.input.points), p.values, p.columns, o.nc,
                         o.table, o.fig, o.metrics, attrs=p.attrs,
                         prov=provenance(snakemake.rule, {"values": p.values, "attrs": p.attrs}))
