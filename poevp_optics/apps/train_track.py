"""Alias of apps/train/train_track.py (issue 29 moved it): the shipped track_net weights' metadata
(assets/predictor/track_net.json and .safetensors) records `python -m poevp_optics.apps.train_track`,
so that command still runs the trainer. Use `python -m poevp_optics.apps.train.train_track`."""

if __name__ == "__main__":
    from poevp_optics.apps.train.train_track import main

    raise SystemExit(main())
