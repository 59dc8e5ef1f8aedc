#include "ua/client/services.hpp"

#include <string>

#include "ua/types/ns0_types_services.hpp"
#include "ua/types/status_codes.hpp"

namespace pnp::ua::client {

Error::Error(StatusCode status, std::string_view message)
    : std::runtime_error(std::string(message) + ": " + status.toString()), status_(status) {}

namespace detail {

void throwUnexpectedResponse(const NodeId& typeId, const Byte* body, std::size_t size,
                             std::string_view service, const DecodeLimits& limits) {
    if (isNs0Numeric(typeId, DataTypeInfo<ServiceFault>::binaryEncodingId)) {
        ServiceFault fault{};
        try {
            BinaryDecoder d(body, size, limits);
            decode(d, fault);
        } catch (const DecodeError& e) {
            throwDecodeError(e, service);
        }
        StatusCode s = fault.responseHeader.serviceResult;
        // A ServiceFault always stands for a failure; a Good code in it is a server bug.
        if (!s.isBad()) s = status::BadUnexpectedError;
        throw Error(s, std::string(service) + " failed (ServiceFault)");
    }
    throw Error(status::BadUnknownResponse,
                std::string(service) + ": unexpected response type " + typeId.toString());
}

void checkServiceResult(const ResponseHeader& header, std::string_view service) {
    if (header.serviceResult.isBad())
        throw Error(header.serviceResult, std::string(service) + " failed");
}

void throwDecodeError(const DecodeError& e, std::string_view service) {
    throw Error(e.status(),
                std::string(service) + ": cannot decode the response (" + e.what() + ")");
}

}  // namespace detail
}  // namespace pnp::ua::client
