"""Reports: report.json, the plan's and verify's summaries, the HTML pages and their plots, VCD waveforms."""
