"""Rule import_recording: a real recording to calib-recording-1 (units declared in the settings)."""
from calib.ingest import import_recording
from calib.core import progress as runlog
from calib.io.netcdf import provenance

with runlog.to_file(snakemake.log[0]):
    s = snakemake.params.settings
    import_recording(s, snakemake.output.recording, prov=provenance(snakemake.rule, s))
    print(f"imported {s.get('sensor', '')} -> {snakemake.output.recording}")
