"""Session recordings: one MCAP file per ``twin drive``, readable by Foxglove and by ``twin replay``.

schemas -- topics, schema names and the JSON Schemas of the channels (Foxglove's well-known ones and ours)
messages -- Frame, GNSS fix and UDM answers -> JSON messages
writer  -- Recorder: an MCAP writer that flushes at least every half second
reader  -- read_recording: every message by topic, also from a file cut off by a killed process
hook    -- RecordingHook (the ``--record`` plugin of ``twin drive``) and SessionRecording
bus     -- how other hooks (the UDM's) find the session's recording
replay  -- kinematic replay and re-simulation of a recording (``twin replay``)

The format is described in docs/recording.md.
"""
