"""Rewrite an MCAP recording so that each LiDAR scan is stored after the frame that follows it
in time (kitti2mcap's order: a drive's frame images first, its scan after them), keeping every
message's log time. For checking that a reader pairs by stamp, not by storage order.

    python experiments/scans_after_frames.py IN.mcap OUT.mcap [--lidar-topic /lidar/points]
"""

from __future__ import annotations

import argparse

from mcap.reader import make_reader
from mcap.writer import Writer


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("input")
    p.add_argument("output")
    p.add_argument("--lidar-topic", default="/lidar/points")
    p.add_argument("--frame-topic", default="/stereo/right/image",
                   help="the last topic of a frame; a held scan is written after it")
    args = p.parse_args()
    with open(args.input, "rb") as f, open(args.output, "wb") as out:
        reader = make_reader(f)
        writer = Writer(out)
        writer.start(profile=reader.get_header().profile, library="scans_after_frames")
        schemas, channels, held = {}, {}, []
        moved = 0
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                            schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding,
                    schemas.get(channel.schema_id, 0), dict(channel.metadata))
            args_ = (channels[channel.id], message.log_time, message.data,
                     message.publish_time, message.sequence)
            if channel.topic == args.lidar_topic:
                held.append(args_)
                continue
            writer.add_message(*args_[:3], publish_time=args_[3], sequence=args_[4])
            if channel.topic == args.frame_topic and held:
                for h in held:
                    writer.add_message(*h[:3], publish_time=h[3], sequence=h[4])
                moved += len(held)
                held = []
        for h in held:
            writer.add_message(*h[:3], publish_time=h[3], sequence=h[4])
        writer.finish()
    print(f"wrote {args.output}: {moved} scans moved after their frames")


if __name__ == "__main__":
    main()
