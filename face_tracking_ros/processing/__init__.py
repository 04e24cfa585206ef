"""Message-in, message-out processors shared by the live nodes and offline bag replay."""
