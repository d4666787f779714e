"""Decode every /world message of a log with the schema the log embeds (mcap's protobuf
decoder) and check it is Foxglove's own foxglove.SceneUpdate; prints the count."""

import sys

from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

with open(sys.argv[1], "rb") as handle:
    reader = make_reader(handle, decoder_factories=[DecoderFactory()])
    count = 0
    for _, channel, message, decoded in reader.iter_decoded_messages(topics=["/world"]):
        assert channel.message_encoding == "protobuf", channel.message_encoding
        assert decoded.DESCRIPTOR.full_name == SceneUpdate.DESCRIPTOR.full_name
        assert SceneUpdate.FromString(message.data).entities, "a scene without entities"
        count += 1
assert count > 0, "no /world message"
print(f"{count} /world messages are foxglove.SceneUpdate")
