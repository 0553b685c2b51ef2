"""Take serialized messages with the publisher's GID and sequence number (rcl through ctypes).

Counting the clouds DDS lost needs, per message, the publication sequence number *and* the
publisher it counts for: two publishers on one topic number their samples independently.
rclpy's ``MessageInfo`` carries the sequence numbers but not the publisher's GID (rmw has it,
in ``rmw_message_info_t.publisher_gid``), and it reaches a callback only when the callback
takes exactly two required arguments. So for the subscriptions that need it, the executor's
take is replaced by ``rcl_take_serialized_message`` called through ctypes on the subscription
rclpy created (``Subscription.handle.pointer``, the ``rcl_subscription_t *``): one copy of the
serialized bytes out of rmw, as rclpy's own raw take makes, and the whole ``rmw_message_info_t``.

Why by hand: no library exposes the GID to Python. The structs below are Jazzy's
(``rmw/types.h``: ``rmw_gid_t`` of 16 bytes since Iron); :func:`taker` checks the library
loads and returns None otherwise, and the node then falls back to rclpy's raw take with its
``MessageInfo`` (sequence numbers without GIDs: one count for all publishers).
"""
from __future__ import annotations

import ctypes
import threading
from typing import Any, NamedTuple

__all__ = ['Taken', 'SerializedTaker', 'taker', 'executor_with_taker']

RCL_RET_OK = 0
RCL_RET_SUBSCRIPTION_TAKE_FAILED = 401
GID_STORAGE_SIZE = 16  # RMW_GID_STORAGE_SIZE in Jazzy


class _Allocator(ctypes.Structure):
    _fields_ = [('allocate', ctypes.c_void_p), ('deallocate', ctypes.c_void_p),
                ('reallocate', ctypes.c_void_p), ('zero_allocate', ctypes.c_void_p),
                ('state', ctypes.c_void_p)]


class _Uint8Array(ctypes.Structure):  # rcutils_uint8_array_t = rmw_serialized_message_t
    _fields_ = [('buffer', ctypes.POINTER(ctypes.c_uint8)), ('buffer_length', ctypes.c_size_t),
                ('buffer_capacity', ctypes.c_size_t), ('allocator', _Allocator)]


class _Gid(ctypes.Structure):
    _fields_ = [('implementation_identifier', ctypes.c_char_p),
                ('data', ctypes.c_uint8 * GID_STORAGE_SIZE)]


class _MessageInfo(ctypes.Structure):  # rmw_message_info_t
    _fields_ = [('source_timestamp', ctypes.c_int64), ('received_timestamp', ctypes.c_int64),
                ('publication_sequence_number', ctypes.c_uint64),
                ('reception_sequence_number', ctypes.c_uint64), ('publisher_gid', _Gid),
                ('from_intra_process', ctypes.c_bool)]


class Taken(NamedTuple):
    """One message as taken: its CDR bytes and where it came from."""

    data: bytes
    publisher: bytes  # the publisher's GID
    seq: int  # its publication sequence number
    source_timestamp: int  # [ns]


class SerializedTaker:
    """``rcl_take_serialized_message`` with the full message info, into one reused buffer."""

    def __init__(self, rcl: Any, rcutils: Any) -> None:
        self._take = rcl.rcl_take_serialized_message
        self._take.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Uint8Array),
                               ctypes.POINTER(_MessageInfo), ctypes.c_void_p]
        self._take.restype = ctypes.c_int
        get_alloc = rcutils.rcutils_get_default_allocator
        get_alloc.restype = _Allocator
        init = rcutils.rcutils_uint8_array_init
        init.argtypes = [ctypes.POINTER(_Uint8Array), ctypes.c_size_t,
                         ctypes.POINTER(_Allocator)]
        init.restype = ctypes.c_int
        self._fini = rcutils.rcutils_uint8_array_fini
        self._fini.argtypes = [ctypes.POINTER(_Uint8Array)]
        self._alloc = get_alloc()
        self._buf = _Uint8Array()
        if init(ctypes.byref(self._buf), 1 << 16, ctypes.byref(self._alloc)) != RCL_RET_OK:
            raise OSError('rcutils_uint8_array_init failed')
        self._info = _MessageInfo()
        self._lock = threading.Lock()

    def take(self, subscription: Any) -> Taken | None:
        """Take the next message of an rclpy subscription; None if there was none.

        Raises:
            OSError: rcl reported an error other than "nothing to take".
        """
        with self._lock, subscription.handle:
            rc = self._take(subscription.handle.pointer, ctypes.byref(self._buf),
                            ctypes.byref(self._info), None)
            if rc == RCL_RET_SUBSCRIPTION_TAKE_FAILED:
                return None
            if rc != RCL_RET_OK:
                raise OSError(f'rcl_take_serialized_message returned {rc}')
            info = self._info
            data = ctypes.string_at(self._buf.buffer, self._buf.buffer_length)
            return Taken(data, bytes(info.publisher_gid.data),
                         int(info.publication_sequence_number), int(info.source_timestamp))

    def __del__(self) -> None:
        try:
            self._fini(ctypes.byref(self._buf))
        except Exception:  # interpreter shutdown: the library may be gone already
            pass


_TAKER: SerializedTaker | None = None
_TAKER_ERROR: str | None = None


def taker() -> SerializedTaker | None:
    """The process's taker (rclpy must be imported first, so rcl is loaded), or None when
    the rcl libraries cannot be used this way (:func:`taker_error` says why)."""
    global _TAKER, _TAKER_ERROR
    if _TAKER is None and _TAKER_ERROR is None:
        import rclpy  # noqa: F401  loads librcl and librcutils into the process
        try:
            _TAKER = SerializedTaker(ctypes.CDLL('librcl.so'), ctypes.CDLL('librcutils.so'))
        except (OSError, AttributeError) as err:
            _TAKER_ERROR = str(err)
    return _TAKER


def taker_error() -> str | None:
    """Why :func:`taker` returned None (None if it did not)."""
    return _TAKER_ERROR


def executor_with_taker(base: type) -> type:
    """A subclass of an rclpy executor class whose take of a subscription with a ``lz_take``
    attribute (a callable ``(subscription) -> args tuple or None``) calls that instead of
    rclpy's take, and passes what it returns to the subscription's callback."""

    from rclpy.exceptions import InvalidHandle

    class TakingExecutor(base):  # type: ignore[misc, valid-type]
        def _take_subscription(self, sub: Any) -> Any:
            take = getattr(sub, 'lz_take', None)
            if take is None:
                return super()._take_subscription(sub)
            try:
                args = take(sub)
            except InvalidHandle:  # destroyed meanwhile (shutdown), as rclpy's own take
                return None
            if args is None:
                return None

            async def _execute() -> None:
                sub.callback(*args)
            return _execute

    TakingExecutor.__name__ = f'Taking{base.__name__}'
    return TakingExecutor
