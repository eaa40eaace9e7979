"""Success and smoothness against injected inference latency (``plain`` / ``scheme`` / ``rtc``).

A thin entry point of :mod:`lerobot_actionflow.evaluation.latency_sweep` (see its docstring for
the options and outputs)::

    python benchmarks/latency_sweep.py --checkpoints='[…/pretrained_model]' \\
        --env.type=actionflow --env.task=Lift --latencies_ms='[0,200,800]' \\
        --eval.n_episodes=10 --eval.batch_size=5 --output_dir=outputs/latency
"""

from lerobot_actionflow.evaluation.latency_sweep import main

if __name__ == "__main__":
    main()
