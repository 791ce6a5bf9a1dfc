"""The CLI's streaming verbs (CLI.md): build --stream, plan --stream, verify --stream, stream."""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

from codegen import __version__, progress
from codegen.cli.outputs import stream_dir
from codegen.errors import BuildError, render_all
from codegen.job import load_job
from codegen.link.host import HostLink
from codegen.pipeline.host import HostBuild, host_build
from codegen.pipeline.normalized import job_fingerprint
from codegen.pipeline.streaming import StreamSetup, build_stream_firmware, stream_chunks, stream_setup
from codegen.report.summaries import human_plan, plan_summary, write_json
from codegen.tables.schedule import RT_PAUSE
from codegen.verify.bounded import RunOutputs
from codegen.verify.heaters import job_faults
from codegen.verify.hold import hold_verify, pauses
from codegen.verify.report_samples import RunSamples
from codegen.verify.stream import simulate_stream, simulate_stream_bounded


def _stream_report(setup: StreamSetup, image, sources: dict[str, str]) -> dict:
    lay = setup.layout
    return {
        "printer_codegen": __version__, "job": setup.config.job_name, "target": setup.target.target,
        "board": setup.target.board, "mcu": setup.target.mcu, "stream": True,
        "identity": f"{setup.identity:08x}",
        "link": {"baud": lay.baud, "baud_error_pct": round(lay.baud_error_pct, 3), "ring_bytes": lay.ring_bytes,
                 "ring_where": lay.where, "payload_bytes": setup.budget.payload},
        "image": {"hex": image.hex_path.name, "elf": image.elf_path.name if image.elf_path else None,
                  "flash_bytes": image.flash_bytes, "flash_capacity": image.flash_capacity,
                  "ram_bytes": image.ram_bytes, "ram_capacity": image.ram_capacity,
                  "flash_parts": dict(image.flash_parts), "sections": dict(image.sections)},
        "sources": sorted(sources),
    }


def _firmware(job, setup: StreamSetup, out: str | None):
    out_dir = stream_dir(job.name, out)
    image, sources = build_stream_firmware(setup, out_dir)
    report = {**_stream_report(setup, image, sources), "job_fingerprint": job_fingerprint(job, setup.config.baud)}
    write_json(out_dir / "report.json", report)
    return image, out_dir


def cmd_build_stream(args) -> int:
    job = load_job(Path(args.job), args.target, program_required=False)
    setup = stream_setup(job)
    image, out_dir = _firmware(job, setup, args.out)
    print(f"built {out_dir / image.hex_path.name}: the streaming firmware for {setup.config.board} "
          f"(identity {setup.identity:08x}): flash {image.flash_bytes} of {image.flash_capacity} bytes, RAM "
          f"{image.ram_bytes} of {image.ram_capacity} bytes; {setup.describe()}")
    return 0


def streamed_host(job, setup: StreamSetup, strict: bool, keep: bool, tables_out=None) -> HostBuild:
    host = host_build(job, strict, keep=keep, tables=tables_out, link=setup.budget)
    if host.warnings:
        print(render_all(host.warnings), file=sys.stderr)
    host.homing = setup.config.homing  # the streaming firmware's homing (codegen/pipeline/streaming.py)
    return host


def cmd_plan_stream(args) -> int:
    job = load_job(Path(args.job), args.target)
    host = streamed_host(job, stream_setup(job, args.baud), args.strict, keep=args.report is not None)
    summary = plan_summary(host)
    print(json.dumps(summary, indent=2) if args.json else human_plan(summary))
    if args.report:  # codegen/report/html.py, with matplotlib: imported only here
        from codegen.report.html import write_plan_report
        write_plan_report(Path(args.report), host, summary)
    return 0 if summary["pass"] else 1


def verify_stream(args) -> tuple[HostBuild, dict, object, RunSamples | None, list[str]]:
    """verify --stream: the job's streaming firmware built and the job streamed to it in the simulator; the host
    build, verify's result (with `link`), the trace, what --report draws where it was gathered as the run was
    compared (else None), and the text's first lines (the CLI prints the rest)."""
    job = load_job(Path(args.job), args.target)
    setup = stream_setup(job, args.baud)
    faults = job_faults(args.fault, tuple(h.name for h in setup.config.heaters))
    image, out_dir = _firmware(job, setup, args.out)
    samples, result, held = None, None, args.hold is not None or args.override is not None
    if bounded(args, setup.target.target, job, streamed=True):
        with tempfile.NamedTemporaryFile(prefix="table-", suffix=".bin") as table:  # the comparison reads it too
            host = _checked(streamed_host(job, setup, args.strict, keep=False, tables_out=table))
            held = runtime_pauses(host)  # M0/M1 wait for resume frames: hold_verify, below
            if not held:
                result, compared = simulate_stream_bounded(host, setup, image, faults, table, args.strict,
                                                           outputs=run_outputs(args))
                trace, samples = compared.trace, compared.samples
    if held and setup.target.target == "avr" and not (args.report or args.vcd):
        # --hold, --override or M0/M1 on an ATmega2560: its tables only, compared a chapter at a time
        host = _checked(streamed_host(job, setup, args.strict, keep="tables"))
        steps_csv = Path(args.trace) if args.trace else None  # written as the run is compared
        args.trace = None
        result, trace = hold_verify(host, image, args.hold, args.override, setup, steps_csv)
    if result is None:  # kept whole: an 8051's, or --report's and --vcd's
        host = _checked(streamed_host(job, setup, args.strict, keep=True))
        if args.hold is not None or args.override is not None or pauses(host):
            result, trace = hold_verify(host, image, args.hold, args.override, setup)
        else:
            result, trace = simulate_stream(host, setup, image, faults)
    lk = result["link"]
    headline = [f"{'PASS' if result['pass'] else 'FAIL'} {job.name}: streamed to {out_dir / 'firmware.hex'} at "
                f"{lk['baud']} baud, {result['duration_s']:.4f} s simulated, {result['planned_duration_s']:.4f} s "
                f"planned",
                f"  link: {lk['bytes']} bytes in {lk['frames']} frames, {lk['retransmits']} retransmitted, lowest "
                f"ring fill {lk['min_ring_fill_bytes']} bytes (planned {lk['planned_min_ring_fill_bytes']}), "
                f"{lk['underruns']} underruns"]
    return host, result, trace, samples, headline


def bounded(args, target: str, job, streamed: bool = False) -> bool:
    """verify compares in bounded memory (codegen/verify/bounded.py): an ATmega2560's flash image without a feed
    hold (its outputs written or gathered as it is compared: run_outputs; one with a feed hold: cmd_verify's
    tables-only path), or a stream with no --hold or --override (an 8051's without --vcd: the waveform is written
    from the simavr harness's records; one with M0/M1 waits for resume frames: runtime_pauses)."""
    requests = args.hold is not None or args.override is not None
    if streamed:
        return not requests and (target == "avr" or (target == "mcs51" and not args.vcd))
    return job.machine.feed_hold is None and not requests and target == "avr"


def runtime_pauses(host: HostBuild) -> bool:
    """The job has M0/M1 pauses among its runtime records (known to a build that keeps nothing else)."""
    return host.runtime is not None and bool((host.runtime.command == RT_PAUSE).any())


def run_outputs(args) -> RunOutputs:
    """--trace's and --vcd's files, written as the run is compared (and taken off `args`: they are done), and
    whether --report's samples are gathered."""
    outputs = RunOutputs(Path(args.trace) if args.trace else None, Path(args.vcd) if args.vcd else None,
                         args.report is not None, resonance=tuple(getattr(args, "resonance", ())))
    args.trace = args.vcd = None
    return outputs


def _checked(host: HostBuild) -> HostBuild:
    if not host.findings.ok:
        raise BuildError(f"{host.job.name}: the tables do not do what the job says:\n  "
                         + "\n  ".join(host.findings.problems))
    return host


def cmd_stream(args) -> int:
    from codegen.link import serial_port

    job = load_job(Path(args.job), args.target)
    setup = stream_setup(job, args.baud)
    motors = len(setup.config.motors)
    with tempfile.TemporaryFile() as table:
        host = streamed_host(job, setup, args.strict, keep=False, tables_out=table)
        if not host.findings.ok:
            raise BuildError(f"{job.name}: the tables do not do what the job says:\n  "
                             + "\n  ".join(host.findings.problems))
        table.seek(0)
        plan = host.link_plan
        chunks = stream_chunks(table.read(), motors)
        link = HostLink(chunks, motors, setup.identity, 10 / setup.layout.baud, plan.prefill_bytes,
                        payload=setup.budget.payload, ping_s=setup.budget.ping_s, stream_bytes=plan.stream_bytes,
                        answer_within_s=serial_port.BOOT_S, latency_s=serial_port.LATENCY_S,
                        heaters=tuple(h.name for h in setup.config.heaters),
                        laser_top=setup.config.laser.top if setup.config.laser else 0)
        port = serial_port.open_port(args.port, setup.layout.baud)
        began = time.monotonic()
        try:
            with serial_port.terminal_keys(setup.config.hold is not None) as keys:
                if setup.config.hold is not None and sys.stdin.isatty():
                    print("keys: ! hold, ~ resume, - and + the feed override", file=sys.stderr)
                interrupted = serial_port.run(link, port, plan.stream_bytes, progress=progress.enabled(),
                                              motors=tuple(m.name for m in setup.config.motors), keys=keys)
        finally:
            port.close()
    took = time.monotonic() - began
    expected = tuple(int(v) for v in host.expected_final - host.start_steps)
    if interrupted and link.outcome in ("aborted", None):  # else the session's own end came before the ABORT
        machine = "did not answer" if link.outcome is None else f"stopped at positions {list(link.position)}"
        print(f"error: interrupted: sent ABORT; the machine {machine}", file=sys.stderr)
        return 1
    if link.outcome != "finished":
        detail = link.message or (f"the firmware reports positions {list(link.position)}" if link.position else "")
        print(f"error: {job.name}: the stream ended {link.outcome}{': ' + detail if detail else ''}", file=sys.stderr)
        return 1
    if link.position != expected:
        print(f"error: {job.name}: the machine ended at {list(link.position)} steps from its start, the job at "
              f"{list(expected)}", file=sys.stderr)
        return 1
    print(f"streamed {job.name} to {args.port}: {link.stats.data_bytes} stream bytes in {took:.1f} s, "
          f"{link.stats.retransmits} frames retransmitted; positions {list(link.position)} as planned")
    return 0
