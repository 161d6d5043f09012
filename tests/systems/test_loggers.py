"""The run's single logger (stt_drake.assembly.loggers): each signal reads back exactly what
a Drake logger of its own records."""

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import (
    ConstantVectorSource,
    Integrator,
    LogVectorOutput,
    Sine,
    VectorLogSink,
)

from stt_drake.assembly.loggers import add_loggers


def test_each_signal_reads_what_its_own_logger_records():
    builder = DiagramBuilder()
    wave = builder.AddSystem(Sine(np.array([1.0, 2.0, 3.0]), np.ones(3), np.array([0.0, 1.0, 2.0])))
    ramp = builder.AddSystem(Integrator(2))  # a state: its log changes with the integration
    rate = builder.AddSystem(ConstantVectorSource(np.array([0.5, -1.0])))
    builder.Connect(rate.get_output_port(), ramp.get_input_port())
    empty = builder.AddSystem(ConstantVectorSource(np.zeros(0)))
    ports = {
        "wave": wave.get_output_port(0),
        "nothing": empty.get_output_port(),
        "ramp": ramp.get_output_port(),
    }
    own = {name: LogVectorOutput(port, builder, 0.1) for name, port in ports.items()}
    logged = add_loggers(builder, ports, 0.1)
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(1.05)
    root = simulator.get_context()

    assert list(logged) == list(ports)
    for name, signal in logged.items():
        log, expected = signal.FindLog(root), own[name].FindLog(root)
        assert log.num_samples() == expected.num_samples() == 11
        np.testing.assert_array_equal(log.sample_times(), expected.sample_times())
        assert log.data().shape == expected.data().shape == (ports[name].size(), 11)
        np.testing.assert_array_equal(log.data(), expected.data())
    shared = {id(signal.sink) for signal in logged.values()}  # one Drake logger for all
    sinks = [s for s in diagram.GetSystems() if isinstance(s, VectorLogSink)]
    assert len(shared) == 1 and len(sinks) == len(own) + 1
    assert logged["ramp"].sink.get_input_port(0).size() == 5


def test_nothing_to_log_adds_no_logger():
    builder = DiagramBuilder()
    assert add_loggers(builder, {}, 0.1) == {}
    assert builder.GetSystems() == []
