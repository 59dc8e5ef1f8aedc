// websocketpp configurations of the dashboard (server) and of its tests (client), internal to
// src/dashboard and tests/dashboard. Written out here instead of deriving from
// websocketpp::config::core because core.hpp includes logger/basic.hpp, which declares its
// constructors with template-ids that C++20 rejects; the stub logger needs no such header.
// Sizes and timeouts are the dashboard's bounds, not websocketpp's 32 MB defaults.
#pragma once

#ifndef ASIO_STANDALONE
#define ASIO_STANDALONE
#endif
#ifndef _WEBSOCKETPP_CPP11_STL_
#define _WEBSOCKETPP_CPP11_STL_
#endif

#include <cstddef>
#include <websocketpp/common/cpp11.hpp>
#include <websocketpp/common/stdint.hpp>
#include <websocketpp/concurrency/basic.hpp>
#include <websocketpp/connection_base.hpp>
#include <websocketpp/endpoint_base.hpp>
#include <websocketpp/extensions/permessage_deflate/disabled.hpp>
#include <websocketpp/http/request.hpp>
#include <websocketpp/http/response.hpp>
#include <websocketpp/logger/levels.hpp>
#include <websocketpp/logger/stub.hpp>
#include <websocketpp/message_buffer/alloc.hpp>
#include <websocketpp/message_buffer/message.hpp>
#include <websocketpp/random/none.hpp>
#include <websocketpp/random/random_device.hpp>
#include <websocketpp/transport/asio/endpoint.hpp>

namespace pnp::dashboard::wsconfig {

namespace ws = websocketpp;

// What both ends share; Rng differs (a client masks its frames with random keys), and the
// largest message each accepts. websocketpp 0.8.2's client drops its connection right after
// the handshake when extensions are disabled, so the client keeps them on (no extension is
// compiled in either way: permessage_deflate is the `disabled` one).
template <class Rng, std::size_t MaxMessageSize, bool EnableExtensions>
struct Common {
    using concurrency_type = ws::concurrency::basic;
    using request_type = ws::http::parser::request;
    using response_type = ws::http::parser::response;
    using message_type = ws::message_buffer::message<ws::message_buffer::alloc::con_msg_manager>;
    using con_msg_manager_type = ws::message_buffer::alloc::con_msg_manager<message_type>;
    using endpoint_msg_manager_type =
        ws::message_buffer::alloc::endpoint_msg_manager<con_msg_manager_type>;
    using elog_type = ws::log::stub;
    using alog_type = ws::log::stub;
    using rng_type = Rng;

    static bool const enable_multithreading = true;
    struct transport_config {
        using concurrency_type = Common::concurrency_type;
        using elog_type = Common::elog_type;
        using alog_type = Common::alog_type;
        using request_type = Common::request_type;
        using response_type = Common::response_type;
        using socket_type = ws::transport::asio::basic_socket::endpoint;
        static bool const enable_multithreading = true;
        static const long timeout_socket_pre_init = 5000;
        static const long timeout_proxy = 5000;
        static const long timeout_socket_post_init = 5000;
        static const long timeout_dns_resolve = 5000;
        static const long timeout_connect = 5000;
        static const long timeout_socket_shutdown = 5000;
    };
    using transport_type = ws::transport::asio::endpoint<transport_config>;
    using endpoint_base = ws::endpoint_base;
    using connection_base = ws::connection_base;

    static const long timeout_open_handshake = 5000;
    static const long timeout_close_handshake = 5000;
    static const long timeout_pong = 5000;
    static const int client_version = 13;  // RFC 6455
    static const ws::log::level elog_level = ws::log::elevel::none;
    static const ws::log::level alog_level = ws::log::alevel::none;
    static const size_t connection_read_buffer_size = 16384;
    static const bool drop_on_protocol_error = false;
    static const bool silent_close = false;
    // An incoming message above this closes its connection with 1009 (message too big).
    static const size_t max_message_size = MaxMessageSize;
    // HTTP requests carry no body the dashboard reads.
    static const size_t max_http_body_size = 64 * 1024;
    static const bool enable_extensions = EnableExtensions;
    struct permessage_deflate_config {
        using request_type = Common::request_type;
        static const bool allow_disabling_context_takeover = true;
        static const uint8_t minimum_outgoing_window_bits = 8;
    };
    using permessage_deflate_type =
        ws::extensions::permessage_deflate::disabled<permessage_deflate_config>;
};

// A page's messages are small actions.
struct Server : Common<ws::random::none::int_generator<uint32_t>, 64 * 1024, false> {
    using type = Server;
};

// The tests' client reads whole snapshots of a synthetic cell.
struct Client : Common<ws::random::random_device::int_generator<uint32_t, ws::concurrency::basic>,
                       16 * 1024 * 1024, true> {
    using type = Client;
};

}  // namespace pnp::dashboard::wsconfig
